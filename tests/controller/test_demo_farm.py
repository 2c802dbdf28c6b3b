"""The demo farm's pond (config/farm.toml): its TOWER.json is the simulated tower camera's exactly,
fitted by `fishfarm calibrate tower` from reference points where that camera sees them
(config/tower_ref.csv, written by ``python -m hil_tests.demo_pond``); the cleaner's config holds
together; the feeder's HIL runs leave the cleaner out."""
import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from controller.cleaning.setup import prepare
from controller.config import Config, load_config
from devices.sim.pond import pond_params
from hil_tests.demo_pond import sim_view
from hil_tests.farm import without_cleaner

ROOT = Path(__file__).resolve().parents[2]
FISHFARM = str(Path(sys.executable).parent / "fishfarm")


@pytest.fixture(scope="module")
def demo():
    return load_config(ROOT / "config" / "farm.toml")


def tower_h(path: Path) -> np.ndarray:
    return np.array(json.loads(path.read_text())["H"], float)


def to_pond(H, uv):
    h = np.c_[uv, np.ones(len(uv))] @ H.T
    return h[:, :2] / h[:, 2:]


def test_the_demo_has_a_20_by_10_m_pond_with_a_drain_and_a_feeder_cleaned_at_start_up(demo):
    c = demo.cleaning
    pond = Polygon(c.outline)
    lo, hi = np.min(c.outline, axis=0), np.max(c.outline, axis=0)
    assert tuple(hi - lo) == (20.0, 10.0) and pond.area == pytest.approx(200.0)
    assert len(c.keepouts) == 2 and all(pond.contains(Polygon(k)) for k in c.keepouts)
    assert c.autostart
    kinds = {s["kind"]: s["driver"] for s in demo.devices.values()}
    assert kinds["thrusters"] == kinds["tower_camera"] == "sim"
    prep = prepare(demo)                       # geometry, dock, TOWER.json, float params, the plan
    assert len(prep.plan.path) > 100
    # the simulated robot powers on at the dock
    start = pond_params(demo, demo.sim["pond"], demo.path).start
    assert Point(start[:2]).distance(Point(c.dock)) < 1e-9


def test_tower_json_maps_every_pixel_of_the_pond_where_the_simulated_camera_sees_it(demo):
    view = sim_view(demo)
    H = tower_h(ROOT / demo.cleaning.tower)
    # every pixel of the pond's image, on a 5-pixel grid, and the pond's corners
    u, v = np.meshgrid(np.arange(0, view.width, 5.0), np.arange(0, view.height, 5.0))
    uv = np.c_[u.ravel(), v.ravel()]
    pond = Polygon(demo.cleaning.outline).buffer(1.0)
    truth = view.to_pond(uv)
    on = np.array([pond.contains(Point(p)) for p in truth])
    assert on.sum() > 1000
    assert np.abs(to_pond(H, uv[on]) - truth[on]).max() < 1e-3          # a millimetre
    corners = np.asarray(demo.cleaning.outline, float)
    assert np.abs(to_pond(H, view.to_pixels(corners)) - corners).max() < 1e-3


def test_the_reference_points_are_where_the_camera_sees_them_and_calibrate_tower_gives_tower_json(demo, tmp_path):
    ref = ROOT / "config" / "tower_ref.csv"
    with open(ref, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["u", "v", "x_m", "y_m"] and len(rows) >= 8
    uv = np.array([(float(r["u"]), float(r["v"])) for r in rows])
    xy = np.array([(float(r["x_m"]), float(r["y_m"])) for r in rows])
    view = sim_view(demo)
    assert np.abs(view.to_pixels(xy) - uv).max() <= 0.0005 + 1e-9       # rounded to a thousandth
    assert ((uv >= 0) & (uv < [view.width, view.height])).all()          # every point in the frame
    out = tmp_path / "TOWER.json"
    done = subprocess.run([FISHFARM, "calibrate", "tower", "--points", str(ref), "--out", str(out)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    mine, theirs = tower_h(out), tower_h(ROOT / demo.cleaning.tower)
    grid = np.array([(u, v) for u in range(0, view.width, 40) for v in range(0, view.height, 40)], float)
    assert np.abs(to_pond(mine, grid) - to_pond(theirs, grid)).max() < 1e-6


def test_the_feeders_hil_runs_leave_the_cleaner_out():
    import tomllib
    raw = without_cleaner(tomllib.loads((ROOT / "config" / "farm.toml").read_text()))
    cfg = Config.model_validate({**raw, "path": "<hil>"})
    assert cfg.cleaning is None
    assert {s["kind"] for s in cfg.devices.values()} == {"contacts", "rail", "dispenser", "thermometer"}
    assert not {"pond", "thrusters", "tower_camera"} & set(cfg.sim)
