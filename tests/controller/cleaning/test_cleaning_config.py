"""``[cleaning]``: absent, no cleaner; every fault is one line naming the file, the key and the fault."""
from __future__ import annotations

import json

import pytest

from controller.cleaning.setup import fingerprint, prepare
from controller.config import load_config
from controller.errors import BadInput

TANK = "[[tank]]\nid = \"T1\"\nstock = 10\nmean_weight_g = 10\nposition_m = 1\nsensors = [\"a\"]\n"


def farm(tmp_path, cleaning: str, H=((0.02, 0, 0), (0, 0.02, 0), (0, 0, 1))):
    tower = tmp_path / "tower.json"
    tower.write_text(json.dumps({"H": H}) if H is not None else "{", encoding="utf-8")
    path = tmp_path / "farm.toml"
    path.write_text(TANK + "[cleaning]\n" + f'tower = "{tower}"\n' + cleaning, encoding="utf-8")
    return path


POND = 'outline = [[0, 0], [20, 0], [20, 10], [0, 10]]\nkeepouts = [[[5, 4], [6, 4], [6, 5], [5, 5]]]\ndock = [1, 1]\n'


def test_no_section_no_cleaner(tmp_path):
    path = tmp_path / "farm.toml"
    path.write_text(TANK, encoding="utf-8")
    assert load_config(path).cleaning is None


def test_a_good_section_plans_the_pond(tmp_path):
    cfg = load_config(farm(tmp_path, POND + "brush_m = 0.6\n[cleaning.float]\nspacing_m = 0.4\n"))
    prep = prepare(cfg)
    assert prep.plan.path.shape[1] == 2 and len(prep.plan.path) > 10 and prep.float_params.spacing_m == 0.4
    assert prep.fingerprint == fingerprint(cfg.cleaning)
    assert cfg.cleaning.recover_after_s == 5.0
    assert load_config(farm(tmp_path, POND + "recover_after_s = 12.5\n")).cleaning.recover_after_s == 12.5
    moved = load_config(farm(tmp_path, POND.replace("[5, 4], [6, 4]", "[5, 3], [6, 3]")))
    assert fingerprint(moved.cleaning) != prep.fingerprint       # a changed pond: another map


@pytest.mark.parametrize("text,key,fault", [
    (POND + "brsh_m = 0.5\n", "cleaning.brsh_m", "unknown key"),
    (POND + "cruise = 1.5\n", "cleaning.cruise", "less than or equal to 1"),
    (POND + "recover_after_s = 0\n", "cleaning.recover_after_s", "greater than 0"),
    (POND + "recover_after = 5\n", "cleaning.recover_after", "unknown key"),
    (POND + "mopup_max_m = -1\n", "cleaning.mopup_max_m", "greater than or equal to 0"),
    (POND + "mopup_max_s = 0\n", "cleaning.mopup_max_s", "greater than 0"),
    (POND + "mopup_m = 10\n", "cleaning.mopup_m", "unknown key"),
    (POND.replace("dock = [1, 1]\n", ""), "cleaning.dock", "Field required"),
    (POND + "[cleaning.float]\nspacing = 0.4\n", "cleaning.float.spacing", "unknown key"),
    (POND + "[cleaning.float]\nspacing_m = -1\n", "cleaning.float.spacing_m", "must be > 0"),
    (POND.replace("dock = [1, 1]", "dock = [30, 1]"), "cleaning.dock", "not on the floor"),
    (POND.replace("dock = [1, 1]", "dock = [5.5, 4.5]"), "cleaning.dock", "not on the floor"),
    (POND.replace("[20, 0], [20, 10]", "[20, 10], [20, 0]"), "cleaning.outline", ""),
])
def test_faults_name_section_and_key(tmp_path, text, key, fault):
    with pytest.raises(BadInput) as err:
        prepare(load_config(farm(tmp_path, text)))
    assert f": {key}: " in str(err.value) and fault in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("H,fault", [(None, "not JSON"), ([[1, 0], [0, 1]], "got shape"),
                                     ([[1, 0, 0], [0, 1, 0], [0, 0, 0]], "singular"),
                                     ([[1, 0, 0], [0, "x", 0], [0, 0, 1]], "expected a 3x3 array of numbers")])
def test_a_tower_file_that_is_no_homography_is_refused_by_name(tmp_path, H, fault):
    with pytest.raises(BadInput, match=fault) as err:
        prepare(load_config(farm(tmp_path, POND, H=H)))
    assert "tower.json" in str(err.value)


DEVICES = "".join(f'[devices.{k}]\nkind = "{k}"\ndriver = "sim"\n' for k in ("contacts", "rail", "dispenser"))


@pytest.mark.parametrize("extra,key,fault", [
    ('[devices.thr]\nkind = "thrusters"\ndriver = "sim"\n', "devices.thr", "needs a [cleaning] section"),
    ("[cleaning]\n" + POND + 'tower = "t.json"\n', "devices", "exactly one thrusters device, found 0"),
])
def test_the_cleaners_devices_and_section_go_together(tmp_path, extra, key, fault):
    from controller.app import Controller
    from devices.clock import ManualClock
    path = tmp_path / "farm.toml"
    path.write_text(TANK + DEVICES + extra, encoding="utf-8")
    with pytest.raises(BadInput) as err:
        Controller(load_config(path), ManualClock())
    assert f": {key}: " in str(err.value) and fault in str(err.value)


def test_the_plan_keeps_its_margin_round_keepouts_and_the_default_keeps_old_maps(tmp_path):
    from shapely.geometry import LineString, Polygon
    drain = Polygon([(5, 4), (6, 4), (6, 5), (5, 5)])
    gaps = {}
    for margin in (0.10, 0.05, 0.0):
        cfg = load_config(farm(tmp_path, POND + f"keepout_margin_m = {margin}\n"))
        path = prepare(cfg).plan.path
        gaps[margin] = LineString(path).distance(drain) - cfg.cleaning.body_radius_m
        assert gaps[margin] >= margin - 1e-6
    assert gaps[0.0] < gaps[0.05] < gaps[0.10]                  # closer, lane by lane, as asked
    default = load_config(farm(tmp_path, POND)).cleaning
    assert default.keepout_margin_m == 0.10
    keys = {k: getattr(default, k) for k in ("outline", "keepouts", "dock", "brush_m", "body_radius_m", "cell_m",
                                             "overlap")}
    import hashlib
    assert fingerprint(default) == hashlib.sha256(json.dumps(keys, sort_keys=True).encode()).hexdigest()[:16]
    assert fingerprint(load_config(farm(tmp_path, POND + "keepout_margin_m = 0.05\n")).cleaning) != \
        fingerprint(default)
    with pytest.raises(BadInput, match="cleaning.keepout_margin_m"):
        load_config(farm(tmp_path, POND + "keepout_margin_m = -0.1\n"))


def test_a_relative_tower_file_is_found_beside_farm_toml_then_from_the_working_directory(tmp_path, monkeypatch):
    """A copied farm run from another directory failed with a bare 'config/TOWER.json: no such
    file', while its feeding charts, relative the same way, were found beside farm.toml."""
    site = tmp_path / "site"
    (site / "cfg").mkdir(parents=True)
    (site / "cfg" / "TOWER.json").write_text(json.dumps({"H": [[0.02, 0, 0], [0, 0.02, 0], [0, 0, 1]]}))
    path = site / "farm.toml"
    path.write_text(TANK + '[cleaning]\ntower = "cfg/TOWER.json"\n' + POND, encoding="utf-8")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert prepare(load_config(path)).H[0, 0] == 0.02                    # beside farm.toml
    (elsewhere / "cfg").mkdir()
    (elsewhere / "cfg" / "TOWER.json").write_text(json.dumps({"H": [[0.05, 0, 0], [0, 0.05, 0], [0, 0, 1]]}))
    assert prepare(load_config(path)).H[0, 0] == 0.02                    # ... before the working directory
    (site / "cfg" / "TOWER.json").unlink()
    assert prepare(load_config(path)).H[0, 0] == 0.05                    # the working directory's
    (elsewhere / "cfg" / "TOWER.json").unlink()
    with pytest.raises(BadInput) as err:
        prepare(load_config(path))
    assert str(err.value) == (f"{path}: cleaning.tower: cfg/TOWER.json: no such file (looked beside farm.toml "
                              "and in the working directory)")
