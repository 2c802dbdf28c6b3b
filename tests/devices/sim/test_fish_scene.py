"""The simulated stereo camera: truth is exact, fish appear where the truth says, flags are right."""
import numpy as np
import pytest

from devices.sim.fish_conditions import underwater_conditions
from devices.sim.fish_paint import render_pair
from devices.sim.fish_scene import SurveyScene, surface_rig, surface_scene, swim, underwater_rig, underwater_scene
from devices.sim.fish_species import SPECIES
from devices.sim.fish_stock import make_fish

SMALL = dict(image_size=(640, 480), focal_px=700.0)


def _lone(rng, rig, fishes_spec, **given):
    """Render fish placed by hand: [(species, length_mm, centre, heading_rad)], calm clear water."""
    cond, tex = underwater_conditions(rng, rig, len(fishes_spec),
                                      dict(clutter="none", bubbles=0, visibility_mm=12000.0, **given))
    fishes = []
    for i, (name, length, centre, heading) in enumerate(fishes_spec):
        f = make_fish(rng, i, SPECIES[name], length, 0.05)
        f.centre, f.heading = np.asarray(centre, float), heading
        fishes.append(f)
    seed = int(rng.integers(1 << 30))
    out = render_pair(np.random.default_rng(seed), rig, fishes, np.zeros((0, 4)), cond, tex, masks=True)
    empty = render_pair(np.random.default_rng(seed), rig, [], np.zeros((0, 4)), cond, tex)
    return out, empty, fishes


@pytest.mark.parametrize("make", [underwater_scene, surface_scene])
def test_truth_pixels_are_the_rig_projection_and_length_is_the_3d_distance(make):
    rig = underwater_rig(**SMALL) if make is underwater_scene else surface_rig(**SMALL)
    for seed in range(3):
        scene = make(np.random.default_rng(seed), rig=rig)
        assert isinstance(scene, SurveyScene) and scene.left.shape == (480, 640, 3) and scene.left.dtype == np.uint8
        assert scene.fish, "a default scene holds fish"
        for f in scene.fish:
            p1, p2 = rig.project(np.array([f.snout_mm, f.fork_mm]))
            np.testing.assert_allclose(f.snout_px, [p1[0], p2[0]], atol=1e-6)
            np.testing.assert_allclose(f.fork_px, [p1[1], p2[1]], atol=1e-6)
            assert f.length_cm == pytest.approx(np.linalg.norm(f.snout_mm - f.fork_mm) / 10, rel=1e-12)
            sp = SPECIES[f.species]
            assert 0.75 < f.weight_g / (sp.a * f.length_cm ** sp.b) < 1.33      # scatter, not a law change


def test_fish_drawn_at_its_truth_pixels_and_fork_sits_in_the_notch_between_the_lobes():
    rig = underwater_rig(**SMALL)
    for name in ("sparus_aurata", "dicentrarchus_labrax", "salmo_salar"):
        (left, right, truths, seen), (eleft, eright, _), _ = _lone(
            np.random.default_rng(1), rig, [(name, 300.0, (0, 1500, -1500), 0.0)])
        t = truths[0]
        assert t["measurable"] and t["fully_visible"]
        for cam, (img, empty) in enumerate(((left, eleft), (right, eright))):
            s, f = t["snout_px"][cam], t["fork_px"][cam]
            mid = np.rint((s + f) / 2).astype(int)
            assert seen[cam][mid[1], mid[0]] == 0
            win = np.s_[mid[1] - 2:mid[1] + 3, mid[0] - 2:mid[0] + 3]
            assert np.abs(img[win].astype(float).mean((0, 1)) - empty[win].astype(float).mean((0, 1))).max() > 10
            axis = (f - s) / np.linalg.norm(f - s)
            normal = np.array([-axis[1], axis[0]])
            beyond = f + 3 * axis
            mask = seen[cam]

            def at(p, mask=mask):
                return mask[int(round(p[1])), int(round(p[0]))]
            assert at(beyond) == -1, "just behind the fork notch is water"
            assert at(f - 4 * axis) == 0, "just ahead of it is fin"
            span = np.linalg.norm(f - s) * 0.25
            ts = np.linspace(1, span, 40)
            assert any(at(beyond + k * normal) == 0 for k in ts), "upper lobe"
            assert any(at(beyond - k * normal) == 0 for k in ts), "lower lobe"


def test_fish_cut_by_the_frame_edge_is_neither_measurable_nor_fully_visible():
    rig = underwater_rig(**SMALL)
    (_, _, truths, _), _, _ = _lone(np.random.default_rng(2), rig, [
        ("sparus_aurata", 300.0, (760, 1500, -1500), 0.0),        # snout past the right edge
        ("sparus_aurata", 300.0, (0, 1500, -1500), 0.0)])
    cut, whole = truths
    assert max(cut["snout_px"][:, 0]) > 639 and not cut["measurable"] and not cut["fully_visible"]
    assert whole["measurable"] and whole["fully_visible"]


def test_fish_behind_a_nearer_one_is_hidden_and_the_nearer_one_is_not():
    rig = underwater_rig(**SMALL)
    far_centre = np.array([0.0, 1900.0, -1500.0])
    L = 300.0
    fork_far = far_centre - [L / 2, 0, 0]                       # heading 0: snout at +x, fork at -x
    c1 = rig.centres[0]
    near_centre = c1 + 0.5 * (fork_far - c1)                    # on the left camera's ray to the fork
    (_, _, truths, seen), _, _ = _lone(np.random.default_rng(3), rig, [
        ("sparus_aurata", L, far_centre, 0.0), ("sparus_aurata", 200.0, near_centre, 0.0)])
    far, near = truths
    np.testing.assert_allclose(far["fork_mm"], fork_far, atol=1e-6)
    assert not far["measurable"] and not far["fully_visible"] and far["hidden"][0] > 0.0
    assert near["measurable"] and near["fully_visible"]
    u, v = np.rint(far["fork_px"][0]).astype(int)
    assert seen[0][v, u] == 1                                   # the near fish is what the left camera sees


def test_same_seed_same_scene_other_seed_other_scene():
    rig = underwater_rig(**SMALL)
    a, b = (underwater_scene(np.random.default_rng(7), rig=rig) for _ in range(2))
    c = underwater_scene(np.random.default_rng(8), rig=rig)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert [f.id for f in a.fish] == [f.id for f in b.fish]
    assert all(np.array_equal(x.snout_mm, y.snout_mm) for x, y in zip(a.fish, b.fish, strict=True))
    assert not np.array_equal(a.left, c.left)


def test_conditions_drawn_per_scene_reported_and_checked():
    rig = underwater_rig(**SMALL)
    scenes = [underwater_scene(np.random.default_rng(s), rig=rig, n_fish=2) for s in range(3)]
    assert all(len(s.fish) <= 2 for s in scenes)
    assert len({s.conditions["visibility_mm"] for s in scenes}) == 3
    fixed = underwater_scene(np.random.default_rng(0), rig=rig, n_fish=1, species="salmo_salar", clutter="net")
    assert fixed.conditions["clutter"] == "net" and all(f.species == "salmo_salar" for f in fixed.fish)
    with pytest.raises(ValueError, match="turbidty"):
        underwater_scene(np.random.default_rng(0), rig=rig, turbidty=3)
    with pytest.raises(ValueError, match="species"):
        surface_scene(np.random.default_rng(0), rig=surface_rig(**SMALL), species="carp")


def test_swim_keeps_ids_and_moves_fish_smoothly():
    rig = underwater_rig(**SMALL)
    fps = 10.0
    frames = list(swim(np.random.default_rng(4), "underwater", 1.0, fps, rig=rig, n_fish=4, bubbles=0))
    assert len(frames) == 10
    seen_ids: set[int] = set()
    for prev, cur in zip(frames, frames[1:], strict=False):
        before = {f.id: f for f in prev.fish}
        for f in cur.fish:
            if f.id in before:
                step = np.linalg.norm(f.snout_mm - before[f.id].snout_mm)
                # at most 1.5 body lengths/s, plus the tail beat's sway at the snout
                assert 0 < step <= 1.5 * 10 * f.length_cm / fps * 1.3 + 5
                assert abs(f.length_cm - before[f.id].length_cm) < 0.02 * f.length_cm
            else:
                assert f.id not in seen_ids and f.id >= max(before), "a new fish gets a new id"
        seen_ids |= set(before)
    assert set(f.id for f in frames[0].fish) & set(f.id for f in frames[-1].fish)
