"""``fishfarm cleaner map --png``: the ledger's coverage map drawn; bad input is one line, exit 2."""
from __future__ import annotations

import json

import numpy as np
import pytest

from controller.cleaning.ledger import Progress
from controller.cleaning.setup import fingerprint
from controller.cli import main
from controller.config import load_config
from controller.store import Store

coverage_map = pytest.importorskip("controller.cleaning.coverage_map")   # the coverage branch's map

TANK = "[[tank]]\nid = \"T1\"\nstock = 10\nmean_weight_g = 10\nposition_m = 1\nsensors = [\"a\"]\n"
POND = ('outline = [[0, 0], [20, 0], [20, 10], [0, 10]]\nkeepouts = [[[5, 4], [6, 4], [6, 5], [5, 5]]]\n'
        'dock = [1, 1]\n')
GREEN = np.array([0x3a, 0x9a, 0x5b]) / 255
PURPLE = np.array([0x8e, 0x44, 0xad]) / 255


def farm(tmp_path, cleaning=POND):
    (tmp_path / "tower.json").write_text(json.dumps({"H": np.eye(3).tolist()}))
    path = tmp_path / "farm.toml"
    section = "" if cleaning is None else f'[cleaning]\ntower = "{tmp_path / "tower.json"}"\n' + cleaning
    path.write_text(f'[store]\npath = "{tmp_path / "ledger.db"}"\n' + TANK + section)
    return path


def save_run(cfg, lanes, give_up=()):
    from controller.cleaning.geometry import pond_geometry
    s = cfg.cleaning
    geom = pond_geometry(s.outline, s.keepouts)
    cmap = coverage_map.CoverageMap(geom, cell_m=s.cell_m, brush_m=s.brush_m, body_radius_m=s.body_radius_m)
    trace = []
    for y in lanes:
        cmap.sweep(1.0, y, 19.0, y)
        trace += [(1.0, y), (19.0, y)]
    for x0, y0, x1, y1 in give_up:                     # the mop-up's account, with the cells it gave up
        cmap.mopup = {"m": 1.0, "s": 10.0, "done": False}
        xs, ys = _centres(cmap)
        cmap.given_up |= (xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1)
    store = Store(cfg.store.path)
    store.save_cleaner(Progress(fingerprint(s), 1, cmap.to_bytes(), 10, "cleaning", "clean", cmap.coverage(), 5.0),
                       np.array(trace))
    store.close()
    return cmap.coverage()


def _centres(cmap):
    rows, cols = cmap.given_up.shape
    xs = cmap.origin[0] + (np.arange(cols) + 0.5) * cmap.cell_m
    ys = cmap.origin[1] + (np.arange(rows) + 0.5) * cmap.cell_m
    return np.meshgrid(xs, ys)


def green_share(png, colour=GREEN):
    import matplotlib.image
    img = matplotlib.image.imread(png)[..., :3]
    return float(np.mean(np.all(np.abs(img - colour) < 0.02, axis=-1)))


def test_the_map_shows_what_was_cleaned(tmp_path, capsys):
    path = farm(tmp_path)
    cfg = load_config(path)
    Store(cfg.store.path).close()
    assert main(["cleaner", "map", "--png", str(tmp_path / "empty.png"), "--config", str(path)]) == 0
    assert "no cleaning run yet" in capsys.readouterr().out
    legend = green_share(tmp_path / "empty.png")                 # the legend's patch: nothing cleaned
    share = save_run(cfg, [1.0, 1.5])
    assert main(["cleaner", "map", "--png", str(tmp_path / "a.png"), "--config", str(path)]) == 0
    assert f"{100 * share:.1f} % cleaned" in capsys.readouterr().out
    more = save_run(cfg, [1.0, 1.5, 2.0, 2.5, 3.0, 6.0, 7.0])
    assert main(["cleaner", "map", "--png", str(tmp_path / "b.png"), "--config", str(path)]) == 0
    a, b = green_share(tmp_path / "a.png") - legend, green_share(tmp_path / "b.png") - legend
    assert legend < 0.002 and 0 < a < b and b / a == pytest.approx(more / share, rel=0.25)


@pytest.mark.parametrize("case,fault", [("no section", "cleaning: no [cleaning] section"),
                                        ("no ledger", "no ledger there"),
                                        ("pond changed", "cleaner: the saved map is of another pond")])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, case, fault):
    path = farm(tmp_path, None if case == "no section" else POND)
    if case == "pond changed":
        save_run(load_config(path), [1.0])
        path = farm(tmp_path, POND.replace("[5, 4], [6, 4]", "[5, 3], [6, 3]"))
    assert main(["cleaner", "map", "--png", str(tmp_path / "m.png"), "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert fault in err and err.count("\n") == 1 and not (tmp_path / "m.png").exists()


def test_the_cells_the_mop_up_gave_up_are_drawn_apart_from_those_still_to_clean(tmp_path, capsys):
    path = farm(tmp_path)
    cfg = load_config(path)
    save_run(cfg, [1.0, 1.5])
    assert main(["cleaner", "map", "--png", str(tmp_path / "none.png"), "--config", str(path)]) == 0
    save_run(cfg, [1.0, 1.5], give_up=[(10.0, 6.0, 14.0, 8.0)])            # a 4 m x 2 m patch, dirty
    assert main(["cleaner", "map", "--png", str(tmp_path / "some.png"), "--config", str(path)]) == 0
    save_run(cfg, [1.0, 1.5], give_up=[(10.0, 6.0, 14.0, 8.0), (2.0, 1.0, 18.0, 1.5)])   # cleaned: not given up
    assert main(["cleaner", "map", "--png", str(tmp_path / "cleaned.png"), "--config", str(path)]) == 0
    legend = green_share(tmp_path / "none.png", PURPLE)
    some = green_share(tmp_path / "some.png", PURPLE) - legend
    cleaned = green_share(tmp_path / "cleaned.png", PURPLE) - legend
    assert legend < 0.002 and some > 0.01
    assert cleaned == pytest.approx(some, rel=0.1) and green_share(tmp_path / "cleaned.png") > legend
