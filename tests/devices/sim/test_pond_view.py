"""The tower camera renderer: exact geometry, the float where the pose says, occlusion, clips.

Where the float is drawn is measured from the frames alone: the frame with the float minus the
same frame without it (everything else is a function of time and seed) gives the float's pixels;
their hue tells orange from blue; their centres go through H to the pond and are compared with
the float marker contract (orange centred on the pose, blue 0.40 m ahead along the heading).
"""
from __future__ import annotations

import csv
import functools
import json
import math

import cv2
import numpy as np
import pytest
import shapely

from devices.sim.pond_view import FloatPose, PondScene, TowerView, main, scenario, tower_view, write_clip

POND = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 10.0], [0.0, 10.0]])
L_POND = np.array([[0.0, 0.0], [12.0, 0.0], [12.0, 4.0], [5.0, 4.0], [5.0, 9.0], [0.0, 9.0]])


def to_pond(H, uv):
    h = np.c_[np.asarray(uv, float).reshape(-1, 2), np.ones(len(uv))] @ np.asarray(H).T
    return h[:, :2] / h[:, 2:3]


def projected(view: TowerView, xyz):
    """Pixel of world points straight from the pinhole model pixel ~ K (R X + t)."""
    cam = np.asarray(xyz, float) @ view.R.T + view.t.ravel()
    h = cam @ view.K.T
    return h[:, :2] / h[:, 2:3]


def float_blobs(scene: PondScene, t_s: float, pose: FloatPose, occlusion: float = 0.0):
    """(orange, blue) float32 weights 0..1 of the float's pixels: how much of each pixel the disc
    covers, estimated by how much it changed against the disc's fully covered pixels."""
    full_with = scene.render(t_s, pose, occlusion=occlusion)
    full_without = scene.render(t_s, None)
    v, u = np.nonzero(np.any(full_with != full_without, axis=-1))
    weights = [np.zeros(full_with.shape[:2], np.float32) for _ in range(2)]
    if len(u) == 0:
        return weights[0], weights[1]
    box = (slice(max(v.min() - 8, 0), v.max() + 9), slice(max(u.min() - 8, 0), u.max() + 9))
    with_float, without = full_with[box], full_without[box].astype(np.float32)
    diff = np.linalg.norm(with_float.astype(np.float32) - without, axis=-1)
    hsv = cv2.cvtColor(with_float, cv2.COLOR_BGR2HSV)
    hue, sat = hsv[..., 0].astype(int), hsv[..., 1].astype(int)
    core_o = (diff > 25) & ((hue <= 25) | (hue >= 170)) & (sat > 80)
    core_b = (diff > 25) & (hue >= 90) & (hue <= 130) & (sat > 60)
    for out, core, other in ((weights[0], core_o, core_b), (weights[1], core_b, core_o)):
        if not core.any():
            continue
        # edge pixels belong to the nearer disc; their weight is their share of the full change
        d_self = cv2.distanceTransform((~core).astype(np.uint8), cv2.DIST_L2, 3)
        d_other = cv2.distanceTransform((~other).astype(np.uint8), cv2.DIST_L2, 3) if other.any() else d_self + 9
        near = (d_self < 2.5) & (d_self < d_other)
        full = np.median(diff[core])
        out[box] = np.where(near, np.clip(diff / full, 0, 1), 0)
    return weights[0], weights[1]


def centre_m(view: TowerView, weight: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(weight > 0.5)
    assert len(u) > 5, "no float pixels found"
    w = weight[weight > 0]
    v, u = np.nonzero(weight > 0)
    return to_pond(view.H, [[np.sum(u * w) / w.sum(), np.sum(v * w) / w.sum()]])[0]


@functools.cache
def _scene(kw: tuple) -> PondScene:
    return PondScene(tower_view(POND, **dict(kw)), POND, seed=5)


def pond_scene(**kw) -> PondScene:
    """One scene per view for the whole module (building one is the slow part)."""
    return _scene(tuple(sorted(kw.items())))


VIEWS = [
    dict(width=1280, height=720),
    dict(width=1920, height=1080, tower_xy=(-4.0, 5.0), tower_height_m=10.0),
    dict(width=800, height=600, tower_xy=(10.0, 5.0), tower_height_m=14.0),   # straight above the pond
    dict(width=720, height=1280, tower_xy=(22.0, -3.0), tower_height_m=9.0),  # portrait, from a corner
]


@pytest.mark.parametrize("kw", VIEWS)
def test_h_is_exact_and_the_pond_fits_in_view(kw):
    view = tower_view(POND, **kw)
    rng = np.random.default_rng(1)
    xy = rng.uniform([-2, -2], [22, 12], (500, 2))
    px = view.to_pixels(xy)
    assert np.allclose(px, projected(view, np.c_[xy, np.zeros(len(xy))]), atol=1e-9)
    assert np.max(np.abs(to_pond(view.H, px) - xy)) < 1e-9
    corners = view.to_pixels(POND)
    assert np.all(corners >= 0) and np.all(corners <= [kw["width"] - 1, kw["height"] - 1])
    # the camera is where its tower is, and sees the pond from above
    if "tower_xy" in kw:
        assert np.allclose(view.centre_m, [*kw["tower_xy"], kw["tower_height_m"]], atol=1e-9)
    assert view.K[0, 2] == (kw["width"] - 1) / 2 and view.K[1, 2] == (kw["height"] - 1) / 2


def test_random_simple_ponds_from_random_towers_fit_in_any_frame():
    rng = np.random.default_rng(11)
    for _ in range(40):
        n = int(rng.integers(3, 12))                           # a star-shaped, so simple, polygon
        a = (np.arange(n) + rng.uniform(0.1, 0.9, n)) * (2 * math.pi / n)
        r = rng.uniform(3, 25, n)
        outline = np.c_[r * np.cos(a), r * np.sin(a)] + rng.uniform(-50, 50, 2)
        assert shapely.Polygon(outline).is_valid
        w, h = int(rng.integers(120, 2000)), int(rng.integers(120, 2000))
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        tower = (rng.uniform(lo[0] - 10, hi[0] + 10), lo[1] - rng.uniform(1, 15))
        view = tower_view(outline, width=w, height=h, tower_xy=tower, tower_height_m=float(rng.uniform(10, 30)))
        px = view.to_pixels(outline)
        assert np.all(px >= 0) and np.all(px <= [w - 1, h - 1]), (w, h, tower)
        assert np.max(np.abs(to_pond(view.H, px) - outline)) < 1e-9 * max(1.0, np.abs(outline).max())


def test_any_simple_outline_fits_and_a_too_narrow_lens_is_refused():
    view = tower_view(L_POND, width=640, height=480)
    px = view.to_pixels(L_POND)
    assert np.all(px >= 0) and np.all(px[:, 0] <= 639) and np.all(px[:, 1] <= 479)
    assert np.ptp(px[:, 0]) > 0.7 * 640 or np.ptp(px[:, 1]) > 0.7 * 480      # and fills the frame
    with pytest.raises(ValueError, match="does not fit"):
        tower_view(POND, hfov_deg=20.0)
    with pytest.raises(ValueError, match="at least 3"):
        tower_view(POND[:2])


@pytest.mark.parametrize("kw", VIEWS)
def test_the_discs_are_where_the_marker_contract_puts_them(kw):
    scene = pond_scene(**kw)
    view = scene.view
    rng = np.random.default_rng(2)
    for heading in (-math.pi + 1e-3, -2.0, -0.7, 0.0, 1.2, 2.6, math.pi):
        x, y = rng.uniform([2.0, 1.5], [18.0, 8.5])
        pose = FloatPose(float(x), float(y), heading)
        orange, blue = float_blobs(scene, 3.0, pose)
        o, b = centre_m(view, orange), centre_m(view, blue)
        ahead = np.array([x + 0.4 * math.cos(heading), y + 0.4 * math.sin(heading)])
        assert np.hypot(*(o - [x, y])) < 0.02, (heading, o, (x, y))
        assert np.hypot(*(b - ahead)) < 0.02, (heading, b, ahead)


def test_the_discs_are_perspective_ellipses_of_the_contract_size():
    view = tower_view(POND, width=1280, height=720, tower_height_m=12.0)
    scene = PondScene(view, POND, seed=1, conditions={"noise": 0.0})
    pose = FloatPose(10.0, 5.0, 0.5)
    orange, blue = float_blobs(scene, 0.0, pose)
    # pixel area of a disc ~ its pond area times the local |det| of the pond -> pixel map
    for mask, r, c in ((orange, 0.2, (10.0, 5.0)), (blue, 0.1, pose.blue_xy())):
        e = 1e-3
        p = view.to_pixels(np.array([c, (c[0] + e, c[1]), (c[0], c[1] + e)]))
        a, b = p[1] - p[0], p[2] - p[0]
        jac = abs(a[0] * b[1] - a[1] * b[0]) / e ** 2
        assert np.sum(mask) == pytest.approx(math.pi * r * r * jac, rel=0.08)


@pytest.mark.parametrize("kind", ["boat", "bird", "spray"])
def test_full_occlusion_hides_the_float_and_half_hides_about_half(kind):
    scene = pond_scene(width=1280, height=720)
    pose = FloatPose(8.0, 4.0, 0.9)
    o0, b0 = (m > 0.5 for m in float_blobs(scene, 1.0, pose))
    with_float = scene.render(1.0, pose, occlusion=1.0, occluder=kind)
    hsv = cv2.cvtColor(with_float, cv2.COLOR_BGR2HSV)
    zone = cv2.dilate((o0 | b0).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    hue, sat = hsv[..., 0][zone], hsv[..., 1][zone]
    assert zone.sum() > 50
    assert not np.any((((hue <= 25) | (hue >= 170)) & (sat > 80)) | ((hue >= 90) & (hue <= 130) & (sat > 60)))
    o5, b5 = (m > 0.5 for m in float_blobs(scene, 1.0, pose, occlusion=0.5))
    shown = (o5.sum() + 4 * b5.sum()) / (o0.sum() + 4 * b0.sum())   # blue counted at orange's scale
    assert 0.25 < shown < 0.75


def test_frames_are_a_function_of_seed_time_and_pose():
    view = tower_view(POND, width=400, height=225)
    a, b = PondScene(view, POND, seed=4), PondScene(view, POND, seed=4)
    pose = FloatPose(6.0, 3.0, 1.0)
    f1 = a.render(2.0, pose)
    a.render(7.5, None, occlusion=0.0)
    assert np.array_equal(f1, a.render(2.0, pose))
    assert np.array_equal(f1, b.render(2.0, pose))
    assert not np.array_equal(f1, PondScene(view, POND, seed=5).render(2.0, pose))
    later = a.render(2.4, pose).astype(int)
    water = a.water > 0.99
    moved = np.abs(later - f1.astype(int)).sum(-1)
    assert moved[water].mean() > 2 * moved[~water].mean()                  # the ripples move
    assert f1.shape == (225, 400, 3) and f1.dtype == np.uint8


def test_bad_arguments_are_named():
    view = tower_view(POND, width=320, height=240)
    with pytest.raises(ValueError, match="wetness"):
        PondScene(view, POND, conditions={"wetness": 1})
    with pytest.raises(ValueError, match="glare"):
        PondScene(view, POND, conditions={"glare": 3})
    with pytest.raises(ValueError, match="foam"):
        PondScene(view, POND, conditions={"foam": True})
    with pytest.raises(ValueError, match="water_bgr"):
        PondScene(view, POND, conditions={"water_bgr": [1, 2]})
    PondScene(view, POND, conditions={"distractors": np.int64(3), "light": np.float32(0.9)})   # numpy numbers do
    scene = PondScene(view, POND)
    with pytest.raises(ValueError, match="occlusion"):
        scene.render(0.0, FloatPose(5, 5, 0), occlusion=1.5)
    with pytest.raises(ValueError, match="scenario"):
        scenario("sunset")


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.reader(fh))


def test_write_clip_follows_the_contract(tmp_path):
    view = tower_view(POND, width=480, height=270)
    scene = PondScene(view, POND, seed=2)
    track = [(0.0, FloatPose(np.float64(5.0), np.float32(5.0), 0), 0.0), (0.04, FloatPose(5.02, 5.0, 0.01), 0.7),
             (0.08, None, 0.0), (0.12, FloatPose(5.06, 5.0, -3.1), 0.3)]
    out = write_clip(tmp_path / "clip", scene, track)
    frames = read_csv(out / "frames.csv")
    assert frames[0] == ["frame", "t_s", "file"] and len(frames) == 5
    truth = read_csv(out / "truth.csv")
    assert truth[0] == ["frame", "t_s", "x_m", "y_m", "heading_rad", "visible"]
    for (i, t, pose, occ), row, frow in zip(((i, *x) for i, x in enumerate(track)), truth[1:], frames[1:], strict=True):
        assert int(row[0]) == i == int(frow[0]) and float(row[1]) == t == float(frow[1])
        img = cv2.imread(str(out / frow[2]), cv2.IMREAD_UNCHANGED)
        assert img.shape == (270, 480, 3)
        assert np.array_equal(img, scene.render(t, pose, occlusion=occ))        # lossless
        if pose is None:
            assert row[2:] == ["", "", "", "0"]
        else:
            assert [float(v) for v in row[2:5]] == [pose.x_m, pose.y_m, pose.heading_rad]
            assert row[5] == ("1" if occ < 0.5 else "0")
    H = np.array(json.loads((out / "tower.json").read_text())["H"])
    assert np.allclose(H, view.H, rtol=0, atol=1e-12)


def test_command_line_writes_a_clip_and_refuses_bad_input(tmp_path, capsys):
    assert main(["straight", "--out", str(tmp_path / "c"), "--width", "320", "--height", "200",
                 "--fps", "10", "--duration", "0.3", "--seed", "1"]) == 0
    rows = read_csv(tmp_path / "c" / "frames.csv")
    assert len(rows) == 4 and cv2.imread(str(tmp_path / "c" / rows[1][2])).shape == (200, 320, 3)
    assert main(["straight", "--out", str(tmp_path / "d"), "--width", "4"]) == 2
    assert "too small" in capsys.readouterr().err
    assert main(["straight", "--out", str(tmp_path / "d"), "--conditions", '{"glare": 7}']) == 2
    assert "glare" in capsys.readouterr().err
    assert main(["straight", "--out", str(tmp_path / "d"), "--conditions", "{oops"]) == 2
    assert main(["glare", "--out", str(tmp_path / "e"), "--width", "160", "--height", "120", "--duration", "0.04",
                 "--conditions", '{"distractors": 3}', "--tower=-3,-3,12"]) == 0
    H = np.array(json.loads((tmp_path / "e" / "tower.json").read_text())["H"])
    view = tower_view(POND, width=160, height=120, tower_xy=(-3, -3), tower_height_m=12)
    assert np.allclose(H, view.H, atol=1e-12)
    assert main(["glare", "--out", str(tmp_path / "f"), "--width", "160", "--height", "120", "--duration", "0.04",
                 "--conditions", '{"distractors": 3}', "--tower=-3,-3,12", "--jpeg", "30"]) == 0
    lossless, jpeg = (cv2.imread(str(tmp_path / d / "000000.png")).astype(int) for d in ("e", "f"))
    assert 0.5 < np.abs(lossless - jpeg).mean() < 12                    # the same frame, with artefacts
    assert main(["glare", "--out", str(tmp_path / "g"), "--jpeg", "0"]) == 2


def colour_blobs(img: np.ndarray, where: np.ndarray, hue_ranges, min_px: int = 4) -> int:
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    hue, sat, val = (hsv[..., i].astype(int) for i in range(3))
    m = np.zeros(hue.shape, bool)
    for lo, hi in hue_ranges:
        m |= (hue >= lo) & (hue <= hi)
    m &= (sat > 100) & (val > 70) & where
    n, _, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8))
    return int(np.sum(stats[1:, cv2.CC_STAT_AREA] >= min_px))


def test_distractor_scenes_hold_orange_and_blue_things_that_are_not_the_float():
    scene, track = scenario("distractors", width=800, height=450, duration_s=0.2, seed=3)
    water = cv2.dilate((scene.water > 0.5).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    empty = scene.render(0.0, None)                         # no float in the pond at all
    assert colour_blobs(empty, water, [(0, 22), (168, 180)]) >= 4
    assert colour_blobs(empty, water, [(95, 125)]) >= 1
    plain = PondScene(scene.view, scene.outline, seed=3, conditions={"distractors": 0, "foam": 0.0, "glare": 0.0})
    assert colour_blobs(plain.render(0.0, None), water, [(0, 22), (168, 180)]) == 0


def spans(mask: np.ndarray, dt: float) -> list[float]:
    """Lengths (s) of the runs of True in a per-frame mask."""
    edges = np.diff(np.r_[0, mask.astype(int), 0])
    return list((np.nonzero(edges == -1)[0] - np.nonzero(edges == 1)[0]) * dt)


@pytest.mark.parametrize("fps", [25.0, 12.5])
def test_scenario_tracks_keep_their_promises(fps):
    outline = shapely.Polygon(POND)
    for name in ("straight", "lawnmower", "turns", "dropouts", "long_occlusion", "glare", "distractors",
                 "washover", "foam"):
        scene, track = scenario(name, width=96, height=54, fps=fps, seed=2)
        t = np.array([x[0] for x in track])
        assert np.allclose(np.diff(t), 1 / fps) and t[0] == 0.0
        poses = [x[1] for x in track]
        assert all(outline.contains(shapely.Point(p.x_m, p.y_m)) for p in poses), name
        h = np.array([p.heading_rad for p in poses])
        assert np.all((h > -math.pi) & (h <= math.pi)), name
        hidden = np.array([x[2] >= 0.5 for x in track])
        runs = spans(hidden, 1 / fps)
        if name == "dropouts":
            assert len(runs) >= 3 and all(0.9 <= r <= 3.2 for r in runs), runs
            assert min(runs) < 1.5 and max(runs) > 2.5
        elif name == "long_occlusion":
            assert len(runs) == 1 and 10.0 <= runs[0] <= 10.4, runs
        else:
            assert not runs, name
    turns = scenario("turns", width=96, height=54, fps=fps)[1]
    h = np.unwrap([x[1].heading_rad for x in turns])
    assert np.ptp(h) > 2 * math.pi                       # spins through +-pi


def test_a_float_out_of_view_or_behind_the_tower_draws_nothing_and_odd_ponds_render():
    view = tower_view(L_POND, width=400, height=300, tower_xy=(2.0, 2.0), tower_height_m=6.0)
    scene = PondScene(view, L_POND, seed=1, conditions={"distractors": 6, "noise": 0.0, "flicker": 0.0})
    empty = scene.render(1.0, None)
    fwd = view.R[2, :2] / np.hypot(*view.R[2, :2])
    behind = view.centre_m[:2] - 30 * fwd
    grid = np.stack(np.meshgrid(np.linspace(-40, 40, 81), np.linspace(-40, 40, 81)), -1).reshape(-1, 2)
    px = view.to_pixels(grid)
    ahead = view.depth(np.c_[grid, np.zeros(len(grid))]) > 2
    aside = grid[ahead & (px[:, 0] < -60)][0]                 # in front of the camera, left of the frame
    for x, y in (behind, aside):
        assert np.array_equal(scene.render(1.0, FloatPose(float(x), float(y), 1.0), occlusion=0.5), empty)
    assert not np.array_equal(scene.render(1.0, FloatPose(3.0, 6.0, 0.3)), empty)


def test_the_float_is_shaded_and_its_paint_varies_from_scene_to_scene():
    view = tower_view(POND, width=640, height=360, tower_height_m=12.0)
    pose = FloatPose(10.0, 5.0, 2.0)
    medians = []
    for seed in (1, 2, 3):
        scene = PondScene(view, POND, seed=seed, conditions={"noise": 0.0, "glare": 0.0, "flicker": 0.0})
        orange, _ = float_blobs(scene, 0.0, pose)
        px = scene.render(0.0, pose)[orange > 0.99].astype(float)
        assert len(px) > 15 and px.std(axis=0).max() > 3.0            # shaded, not one flat colour
        medians.append(np.median(px, axis=0))
    spread = max(np.abs(a - b).max() for a in medians for b in medians)
    assert spread > 8.0                                                 # no one fixed RGB to key on


def test_glare_puts_saturated_glints_near_the_float_and_foam_whitens_the_water():
    scene, track = scenario("glare", width=640, height=360, duration_s=2.0, seed=1)
    t, pose, _ = track[25]
    near = np.hypot(*(scene.view.to_pond(np.argwhere(np.ones((360, 640)))[:, ::-1]) - [pose.x_m, pose.y_m]).T)
    near = (near < 2.0).reshape(360, 640) & (scene.water > 0.99)
    glints = [np.all(scene.render(t + k * 0.2, None) >= 250, axis=-1)[near].sum() for k in range(5)]
    assert min(glints) > 0 and len(set(glints)) > 1                     # there, and twinkling
    water = scene.water > 0.99

    def white(img):
        hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
        return np.mean((hsv[..., 2] > 150)[water] & (hsv[..., 1] < 60)[water])
    cond = {"glare": 0.0, "noise": 0.0}
    frothy = PondScene(scene.view, POND, seed=4, conditions={**cond, "foam": 0.3})
    calm = PondScene(scene.view, POND, seed=4, conditions={**cond, "foam": 0.0})
    assert white(frothy.render(1.0, None)) > 0.05 > white(calm.render(1.0, None)) * 5


def test_washover_hides_part_of_the_float_some_of_the_time_never_all_of_it():
    view = tower_view(POND, width=640, height=360, tower_height_m=12.0)
    dry = PondScene(view, POND, seed=2, conditions={"washover": 0.0, "noise": 0.0})
    wet = PondScene(view, POND, seed=2, conditions={"washover": 1.0, "noise": 0.0})
    pose = FloatPose(9.0, 4.0, -0.4)
    full = (float_blobs(dry, 0.0, pose)[0] > 0.5).sum()
    shown = [(float_blobs(wet, t, pose)[0] > 0.5).sum() / full for t in np.arange(0.0, 3.5, 0.25)]
    assert min(shown) < 0.85 and max(shown) > 0.97 and min(shown) > 0.3


def test_cloud_shadows_darken_patches_of_the_pond_and_drift():
    view = tower_view(POND, width=480, height=270)
    cond = {"noise": 0.0, "flicker": 0.0, "glare": 0.0, "ripple": 0.0, "foam": 0.0}
    sunny = PondScene(view, POND, seed=6, conditions={**cond, "clouds": 0.0})
    cloudy = PondScene(view, POND, seed=6, conditions={**cond, "clouds": 1.0})
    water = sunny.water > 0.99

    def shade(t):
        lit = np.maximum(sunny.render(t, None).astype(float).sum(-1), 1)
        return (cloudy.render(t, None).astype(float).sum(-1) / lit)[water]
    now, later = shade(0.0), shade(8.0)
    assert now.min() < 0.8 and np.mean(now > 0.98) > 0.1            # shadowed patches and sunlit water
    assert np.mean(np.abs(now - later) > 0.1) > 0.05                 # the shadows have moved on
