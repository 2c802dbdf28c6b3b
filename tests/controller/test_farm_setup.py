"""What ``fishfarm run`` checks of a farm as a whole before anything starts (controller/farm_setup.py):
each fault is BadInput naming the file and the key, before a simulator or a device is up."""
from __future__ import annotations

import shutil
import tomllib
from pathlib import Path

import pytest
import tomli_w

from controller.config import load_config
from controller.errors import BadInput
from controller.farm_setup import check_farm
from controller.feeding.rations import load_species

ROOT = Path(__file__).resolve().parents[2]
HOPPER_G, PORTION_ROOM = 8000.0, 1.5          # the demo's hopper; room for an unmeasured auger's +50 %


def farm(tmp_path: Path, edit) -> Path:
    """The demo farm with its chart beside it, ``edit``ed (a function of the raw TOML)."""
    raw = tomllib.loads((ROOT / "config" / "farm.toml").read_text())
    (tmp_path / "feeding").mkdir(exist_ok=True)
    shutil.copy(ROOT / "config" / "feeding" / "sparus_aurata.toml", tmp_path / "feeding")
    edit(raw)
    path = tmp_path / "farm.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


def fault(path: Path, species=None) -> str | None:
    try:
        check_farm(load_config(str(path)), species or load_species())
    except BadInput as exc:
        return str(exc)
    return None


def test_the_demo_farm_passes(tmp_path):
    assert fault(farm(tmp_path, lambda raw: None)) is None


@pytest.mark.parametrize("portion_g, ok", [(0.98 * HOPPER_G / PORTION_ROOM - 0.5, True),
                                           (0.98 * HOPPER_G / PORTION_ROOM + 0.5, False),
                                           (HOPPER_G - 1, False), (9000.0, False)])
def test_a_portion_a_full_hopper_cannot_hold_is_refused(tmp_path, portion_g, ok):
    """A probe's portion_g 9000 g with an 8000 g hopper sent the robot to the box 20,772 times in a
    minute and fed nothing: a refill fills 98 % of the hopper, and a portion needs room for the
    auger's overshoot (+50 % while its rate is a guess)."""
    path = farm(tmp_path, lambda raw: raw["feeding"].update(portion_g=portion_g, hopper_capacity_g=HOPPER_G))
    got = fault(path)
    if ok:
        assert got is None
    else:
        assert got is not None and got.startswith(f"{path}: feeding.portion_g: {portion_g:g} g does not fit")
        assert "at most 5226 g" in got


def test_a_chart_for_a_species_species_toml_does_not_know_is_refused(tmp_path):
    """A typo in a chart's species left it unused: sea bream fed by species.toml's rows, which know
    no temperature (twice the chart's rate at 14 degC, a probe found)."""
    path = farm(tmp_path, lambda raw: None)
    chart = tmp_path / "feeding" / "sparus_aurata.toml"
    chart.write_text(chart.read_text().replace('species = "sparus_aurata"', 'species = "sparus_auratta"'))
    got = fault(path)
    assert got is not None and got.startswith(f"{path}: feeding.tables.0: sparus_aurata.toml is a chart for "
                                              "'sparus_auratta', a species species.toml does not know")


def test_a_missing_chart_names_the_farm_file_and_the_key(tmp_path):
    path = farm(tmp_path, lambda raw: raw["feeding"].update(tables=["feeding/sparus_aurata.toml", "feeding/no.toml"]))
    got = fault(path)
    assert got is not None and got.startswith(f"{path}: feeding.tables.1: ") and got.endswith("no.toml: no such file")


@pytest.mark.parametrize("stock, key", [({"species": "sparus_aurata", "a": 0.012, "b": 3.0, "sorce": "x"},
                                         "stocks.nursery.sorce"),
                                        ({"species": "sparus_aurata", "a": -0.012, "b": 3.0}, "stocks.nursery.a"),
                                        ({"species": "sparus_auratta", "a": 0.012, "b": 3.0},
                                         "stocks.nursery.species"),
                                        ({"a": 0.012, "b": 3.0}, "stocks.nursery.species"),
                                        # each in its bounds, weighing nothing (a survey refused it)
                                        ({"species": "sparus_aurata", "a": 1e-30, "b": 3.0}, "stocks.nursery.a"),
                                        ({"species": "sparus_aurata", "a": 0.9, "b": 4.0}, "stocks.nursery.a")])
def test_stock_sections_are_checked_though_only_a_survey_uses_them(tmp_path, stock, key):
    path = farm(tmp_path, lambda raw: raw.update(stocks={"nursery": stock}))
    got = fault(path)
    assert got is not None and got.startswith(f"{path}: {key}"), got


def test_the_paper_s_nursery_stock_is_taken(tmp_path):
    path = farm(tmp_path, lambda raw: raw.update(stocks={"nursery": {"species": "sparus_aurata", "a": 0.012,
                                                                     "b": 3.032, "source": "Table I"}}))
    assert fault(path) is None


def test_species_rows_out_of_order_are_refused_when_the_species_file_is_read(tmp_path):
    """A species with no chart is fed by its rows, looked up in order: rows out of order were an
    internal error once the simulator had started."""
    text = (ROOT / "config" / "species.toml").read_text()
    raw = tomllib.loads(text)
    rows = raw["sparus_aurata"]["feeding"]
    raw["sparus_aurata"]["feeding"] = [rows[1], rows[0], *rows[2:]]
    path = tmp_path / "species.toml"
    path.write_text(tomli_w.dumps(raw))
    with pytest.raises(BadInput) as err:
        load_species(path)
    assert str(err.value).startswith(f"{path}: sparus_aurata: feeding rows' up_to_g must increase strictly")


@pytest.mark.parametrize("where, said", [("{tmp}", "a directory, not a chart"), ("/dev/null", "not a regular file")])
def test_a_chart_that_is_no_file_says_what_it_is(tmp_path, where, said):
    """An outside tester: /tmp and /dev/null as a chart were each "no such file"."""
    chart = where.replace("{tmp}", str(tmp_path))
    path = farm(tmp_path, lambda raw: raw["feeding"].update(tables=[chart]))
    got = fault(path)
    assert got is not None and got.startswith(f"{path}: feeding.tables.0: ") and got.endswith(f"{chart}: {said}"), got


@pytest.mark.parametrize("change, key", [
    (lambda raw: raw["devices"]["dispenser"].update(port=raw["scada"]["port"]), "devices.dispenser.port"),
    (lambda raw: raw.update(bus={"listen": [f"tcp/127.0.0.1:{raw['scada']['port']}"]}), "bus.listen.0"),
])
def test_two_of_the_farm_s_servers_on_one_port_are_refused(tmp_path, change, key):
    """A simulated dispenser given [scada]'s port took it, and the SCADA server only alarmed."""
    path = farm(tmp_path, change)
    got = fault(path)
    assert got is not None and got.startswith(f"{path}: {key}: port ") and "scada.port" in got, got


def test_ports_left_to_the_system_never_clash(tmp_path):
    path = farm(tmp_path, lambda raw: (raw["scada"].update(port=0), raw["devices"]["dispenser"].update(port=0)))
    assert fault(path) is None


@pytest.mark.parametrize("where, said", [("{tmp}/farm.toml", "a file, not a directory"),
                                         ("{tmp}/farm.toml/surveys", "is a file"),
                                         ("/proc/surveys", "nothing can be made in /proc")])
def test_a_survey_directory_that_cannot_be_is_refused_on_load(tmp_path, where, said):
    """An outside tester: a file, or /proc, as surveys.out_dir was taken; each survey would have
    failed at its end, its OUT.json unwritten."""
    out = where.replace("{tmp}", str(tmp_path))
    path = farm(tmp_path, lambda raw: raw.setdefault("surveys", {}).update(out_dir=out))
    got = fault(path)
    assert got is not None and got.startswith(f"{path}: surveys.out_dir: {out}: ") and said in got, got
    assert not Path("/proc/surveys").exists()


def test_a_survey_directory_still_to_make_is_not_made_by_the_check(tmp_path):
    out = tmp_path / "a" / "b" / "surveys"
    path = farm(tmp_path, lambda raw: raw.setdefault("surveys", {}).update(out_dir=str(out)))
    assert fault(path) is None and not (tmp_path / "a").exists()
