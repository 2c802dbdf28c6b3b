"""The simulated stereo camera: truth is exact, fish appear where the truth says, flags are right."""
import cv2
import numpy as np
import pytest

from devices.sim.fish_body import build_mesh
from devices.sim.fish_conditions import underwater_conditions
from devices.sim.fish_paint import render_pair
from devices.sim.fish_scene import (
    SurveyScene,
    still_in,
    surface_rig,
    surface_scene,
    swim,
    underwater_rig,
    underwater_scene,
    underwater_water,
)
from devices.sim.fish_species import SPECIES
from devices.sim.fish_stock import clear_of, make_fish, segment_distances

SMALL = dict(image_size=(640, 480), focal_px=700.0)
TINY = dict(image_size=(320, 240), focal_px=350.0)     # same view, quicker


def _lone(rng, rig, fishes_spec, pose=(0.0, 0.0, 0.0), plain=False, **given):
    """Render fish placed by hand: [(species, length_mm, centre, heading_rad)] with (pitch, roll,
    curvature) ``pose``, in calm clear water; ``plain``: the species' own outline (no individual
    fork depth or fin wear)."""
    cond, tex = underwater_conditions(rng, rig, len(fishes_spec),
                                      dict(clutter="none", bubbles=0, particles=0, visibility_mm=12000.0,
                                           jpeg_quality=None, **given))
    fishes = []
    for i, (name, length, centre, heading) in enumerate(fishes_spec):
        f = make_fish(rng, i, SPECIES[name], length, 0.05)
        f.centre, f.heading = np.asarray(centre, float), heading
        f.pitch, f.roll, f.curvature = pose
        if plain:
            f.mesh = build_mesh(SPECIES[name], length)
        fishes.append(f)
    seed = int(rng.integers(1 << 30))
    out = render_pair(np.random.default_rng(seed), rig, fishes, np.zeros((0, 4)), cond, tex, masks=True)
    empty = render_pair(np.random.default_rng(seed), rig, [], np.zeros((0, 4)), cond, tex)
    return out, empty, fishes


@pytest.mark.parametrize("make", [underwater_scene, surface_scene])
def test_truth_pixels_are_the_rig_projection_and_length_is_the_3d_distance(make):
    rig = underwater_rig(**TINY) if make is underwater_scene else surface_rig(**TINY)
    for seed in range(3):
        scene = make(np.random.default_rng(seed), rig=rig, n_fish=6)
        assert isinstance(scene, SurveyScene) and scene.left.shape == (240, 320, 3) and scene.left.dtype == np.uint8
        assert scene.fish, "a default scene holds fish"
        for f in scene.fish:
            p1, p2 = rig.project(np.array([f.snout_mm, f.fork_mm]))
            np.testing.assert_allclose(f.snout_px, [p1[0], p2[0]], atol=1e-6)
            np.testing.assert_allclose(f.fork_px, [p1[1], p2[1]], atol=1e-6)
            assert f.length_cm == pytest.approx(np.linalg.norm(f.snout_mm - f.fork_mm) / 10, rel=1e-12)
            sp = SPECIES[f.species]
            assert 0.75 < f.weight_g / (sp.a * f.length_cm ** sp.b) < 1.33      # scatter, not a law change


def _fork_in_notch(seen: np.ndarray, snout: np.ndarray, fork: np.ndarray) -> bool:
    """Just behind the fork point is water, just ahead of it fin, and behind it, on either side
    of the snout-fork line, the two lobes."""
    axis = (fork - snout) / np.linalg.norm(fork - snout)
    normal = np.array([-axis[1], axis[0]])

    def at(p):
        return seen[int(round(p[1])), int(round(p[0]))]

    beyond = fork + 2.5 * axis
    ks = np.linspace(1, 0.25 * np.linalg.norm(fork - snout), 40)
    # the notch is a narrow V: which pixel row holds its apex depends on sub-pixel position
    water = any(at(beyond + d * normal) == -1 for d in (-0.5, 0.0, 0.5))
    return (water and at(fork - 4 * axis) == 0
            and any(at(beyond + k * normal) == 0 for k in ks) and any(at(beyond - k * normal) == 0 for k in ks))


def test_fish_drawn_at_its_truth_pixels_and_fork_sits_in_the_notch_between_the_lobes():
    rig = underwater_rig(**SMALL)
    for name in ("sparus_aurata", "dicentrarchus_labrax", "salmo_salar"):
        (left, right, truths, seen), (eleft, eright, _), _ = _lone(
            np.random.default_rng(1), rig, [(name, 300.0, (0, 1500, -1493), 0.0)], plain=True)
        t = truths[0]
        assert t["measurable"] and t["fully_visible"]
        for cam, (img, empty) in enumerate(((left, eleft), (right, eright))):
            s, f = t["snout_px"][cam], t["fork_px"][cam]
            mid = np.rint((s + f) / 2).astype(int)
            assert seen[cam][mid[1], mid[0]] == 0
            win = np.s_[mid[1] - 2:mid[1] + 3, mid[0] - 2:mid[0] + 3]
            assert np.abs(img[win].astype(float).mean((0, 1)) - empty[win].astype(float).mean((0, 1))).max() > 10
            assert _fork_in_notch(seen[cam], s, f)


def test_fork_stays_in_the_notch_for_oblique_pitched_rolled_bent_fish():
    # up to 45 deg off side-on: beyond that the notch, foreshortened by cos(yaw), is under the
    # 2 px probe at this image scale (it is still drawn; the probe cannot see it)
    rig = underwater_rig(**SMALL)
    rng = np.random.default_rng(5)
    for trial, yaw in enumerate((-45, -30, 0, 25, 40, 45)):
        name = ("sparus_aurata", "dicentrarchus_labrax")[trial % 2]
        heading = np.radians(yaw) + np.pi * (trial % 3 == 0)
        centre = (rng.uniform(-150, 150), rng.uniform(1300, 1700), -1500 + rng.uniform(-100, 100))
        pose = (np.radians(rng.uniform(-20, 20)), np.radians(rng.uniform(-20, 20)), rng.uniform(-3e-4, 3e-4))
        (_, _, truths, seen), _, _ = _lone(rng, rig, [(name, 300.0, centre, heading)], pose, plain=True)
        for cam in (0, 1):
            assert _fork_in_notch(seen[cam], truths[0]["snout_px"][cam], truths[0]["fork_px"][cam]), (trial, cam)


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
    rig = underwater_rig(**TINY)
    a, b = (underwater_scene(np.random.default_rng(7), rig=rig) for _ in range(2))
    c = underwater_scene(np.random.default_rng(8), rig=rig)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert [f.id for f in a.fish] == [f.id for f in b.fish]
    assert all(np.array_equal(x.snout_mm, y.snout_mm) for x, y in zip(a.fish, b.fish, strict=True))
    assert not np.array_equal(a.left, c.left)
    clips = [list(swim(np.random.default_rng(3), "surface", 0.3, 10, rig=surface_rig(**TINY))) for _ in range(2)]
    assert all(np.array_equal(x.left, y.left) and np.array_equal(x.right, y.right)
               for x, y in zip(*clips, strict=True))


def test_conditions_drawn_per_scene_reported_and_checked():
    rig = underwater_rig(**TINY)
    scenes = [underwater_scene(np.random.default_rng(s), rig=rig, n_fish=2) for s in range(3)]
    assert all(len(s.fish) <= 2 for s in scenes)
    assert len({s.conditions["visibility_mm"] for s in scenes}) == 3
    fixed = underwater_scene(np.random.default_rng(0), rig=rig, n_fish=1, species="salmo_salar", clutter="net")
    assert fixed.conditions["clutter"] == "net" and all(f.species == "salmo_salar" for f in fixed.fish)
    with pytest.raises(ValueError, match="turbidty"):
        underwater_scene(np.random.default_rng(0), rig=rig, turbidty=3)
    with pytest.raises(ValueError, match="clutter"):
        underwater_scene(np.random.default_rng(0), rig=rig, clutter="kelp")
    with pytest.raises(ValueError, match="n_fish"):
        underwater_scene(np.random.default_rng(0), rig=rig, n_fish=-1)
    with pytest.raises(ValueError, match="species"):
        surface_scene(np.random.default_rng(0), rig=surface_rig(**TINY), species="carp")


def test_rock_and_cage_backdrops_only_when_given_and_behind_every_fish():
    rig = underwater_rig(**SMALL)
    drawn = {underwater_conditions(np.random.default_rng(s), rig, 0, {})[0]["clutter"] for s in range(200)}
    assert drawn == {"none", "net", "reef"}        # the benches' seeds draw what they always drew

    def detail(img):        # local contrast: what a backdrop adds to the smooth water
        g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float32)
        return float(np.std(g - cv2.GaussianBlur(g, (0, 0), 8)))

    quiet = dict(n_fish=0, bubbles=0, particles=0, noise_sd=0.0, jpeg_quality=None, visibility_mm=12000.0,
                 blur_gain=0.0, sun_rays=0.0)
    for seed in range(4):
        plain = underwater_scene(np.random.default_rng(seed), rig=rig, clutter="none", **quiet)
        for kind in ("rock", "cage"):
            sc = underwater_scene(np.random.default_rng(seed), rig=rig, clutter=kind, **quiet)
            assert sc.conditions["clutter"] == kind
            assert sc.conditions["clutter_range_mm"] > max(sc.conditions["range_mm"])
            tone = np.asarray(sc.conditions["clutter_tone"])
            assert np.all(tone < 0.7) or np.all(tone > 1.0)     # darker or brighter than the water, never alike
            assert detail(sc.left) > 3 * detail(plain.left) + 1.0, (kind, seed)
            assert detail(sc.right) > 3 * detail(plain.right) + 1.0, (kind, seed)
    with pytest.raises(ValueError, match="none, net, reef, rock, cage"):
        underwater_scene(np.random.default_rng(0), rig=rig, clutter="kelp")


@pytest.mark.parametrize("setup", ["underwater", "surface"])
def test_swim_keeps_ids_and_moves_fish_smoothly(setup):
    rig = underwater_rig(**TINY) if setup == "underwater" else surface_rig(**TINY)
    fps = 10.0
    frames = list(swim(np.random.default_rng(4), setup, 1.0, fps, rig=rig, n_fish=4, bubbles=0))
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
                assert f.id not in seen_ids and f.id > max(before), "a new fish gets a new id"
        seen_ids |= set(before)
    assert set(f.id for f in frames[0].fish) & set(f.id for f in frames[-1].fish)


def test_surface_fish_seen_from_above_at_its_truth_pixels_with_its_shadow_elsewhere():
    from devices.sim.fish_conditions import surface_conditions
    rig = surface_rig(**SMALL)
    rng = np.random.default_rng(9)
    cond, tex = surface_conditions(rng, rig, 1, dict(bubbles=0, jpeg_quality=None, glare_strength=0.0, sheen=0.0,
                                                     lamps=[[0.0, -1000.0, 1000.0]], shade=0.5))
    f = make_fish(rng, 0, SPECIES["sparus_aurata"], 120.0, 0.05)
    f.centre, f.heading = np.array([0.0, 0.0, -150.0]), 0.3
    seed = int(rng.integers(1 << 30))
    left, right, truths, seen = render_pair(np.random.default_rng(seed), rig, [f], np.zeros((0, 4)), cond, tex,
                                            masks=True)
    eleft, _, _ = render_pair(np.random.default_rng(seed), rig, [], np.zeros((0, 4)), cond, tex)
    t = truths[0]
    assert t["measurable"] and t["fully_visible"]
    assert abs(t["snout_mm"][2] - t["fork_mm"][2]) < 1.0           # level fish: both ends at one depth
    s, fk = t["snout_px"][0], t["fork_px"][0]
    mid = np.rint((s + fk) / 2).astype(int)
    assert seen[0][mid[1], mid[0]] == 0
    win = np.s_[mid[1] - 1:mid[1] + 2, mid[0] - 1:mid[0] + 2]
    assert np.abs(left[win].astype(float).mean((0, 1)) - eleft[win].astype(float).mean((0, 1))).max() > 10
    # the lamp stands towards -y: the shadow falls towards +y on the floor, i.e. up the image
    # (image-up is world +y), away from the fish itself
    shadow = eleft.astype(float).sum(2) - left.astype(float).sum(2)
    shadow[seen[0] >= 0] = 0
    v, u = np.unravel_index(np.argmax(cv2.GaussianBlur(shadow, (0, 0), 3)), shadow.shape)
    assert v < mid[1] - 20
    assert shadow[max(v - 3, 0):v + 4, max(u - 3, 0):u + 4].mean() > 10


def test_flags_are_consistent_over_many_scenes():
    rig = underwater_rig(**TINY)
    seen_cut = seen_whole = 0
    for seed in range(6):
        for f in underwater_scene(np.random.default_rng(100 + seed), rig=rig).fish:
            inside = all(np.all((p >= 0) & (p <= [319, 239])) for p in (f.snout_px, f.fork_px))
            assert f.measurable <= inside and f.fully_visible <= f.measurable
            assert f.fully_visible <= (max(f.hidden) < 0.1)
            seen_cut += not inside
            seen_whole += f.fully_visible
    assert seen_cut and seen_whole            # scenes hold both fish cut by the frame and whole ones


def test_swimming_fish_leave_the_view_and_new_ones_enter_from_the_sides():
    rig = underwater_rig(**TINY)
    frames = list(swim(np.random.default_rng(6), "underwater", 8.0, 4.0, rig=rig, n_fish=3, bubbles=0,
                       particles=0))
    first = {f.id for f in frames[0].fish}
    later = set().union(*({f.id for f in fr.fish} for fr in frames[1:]))
    assert first - {f.id for f in frames[-1].fish}, "some fish left"
    newcomers = later - first
    assert newcomers, "new fish came in"
    for fid in newcomers:
        k = next(i for i, fr in enumerate(frames) if fid in {f.id for f in fr.fish})
        f = next(f for f in frames[k].fish if f.id == fid)
        u = (f.snout_px[0, 0] + f.fork_px[0, 0]) / 2
        assert u < 0.25 * 320 or u > 0.75 * 320, "a newcomer appears at a side of the view"


def test_worn_or_shallow_caudal_fins_keep_the_fork_notch_innermost():
    from devices.sim.fish_body import _caudal_outline
    L = 250.0
    for name, sp in SPECIES.items():
        for seed in range(5):
            outline, _ = _caudal_outline(sp, L, 20.0, 16.0, 0.8, fork_scale=0.7, wear=1.0,
                                         rng=np.random.default_rng(seed))
            top, bottom = np.argmax(outline[:, 1]), np.argmin(outline[:, 1])      # the two lobe tips
            trailing = outline[top:bottom + 1]
            innermost = trailing[np.argmin(trailing[:, 0])]
            np.testing.assert_allclose(innermost, [L, 0.0], err_msg=name)
            assert np.sum(np.all(np.isclose(trailing, [L, 0.0]), axis=1)) == 1
            mesh = build_mesh(sp, L, None, fork_scale=0.7, wear=1.0, rng=np.random.default_rng(seed))
            np.testing.assert_allclose(mesh.verts[mesh.fork_vertex], [L, 0.0, 0.0])


def test_the_two_cameras_sensor_noise_is_independent():
    """Shifted copies of one noise pattern in both images would hand a stereo matcher a false
    match at the shift: the noise residuals of an empty, flat scene must not correlate at any
    shift."""
    rig = underwater_rig(**TINY)
    sc = underwater_scene(np.random.default_rng(2), rig=rig, n_fish=0, clutter="none", bubbles=0, particles=0,
                          sun_rays=0.0, jpeg_quality=None, noise_sd=4.0)
    res = [g - cv2.GaussianBlur(g, (0, 0), 3) for g in
           (cv2.cvtColor(im, cv2.COLOR_BGR2GRAY).astype(np.float32) for im in (sc.left, sc.right))]
    patch = res[0][80:160, 100:220]
    ncc = cv2.matchTemplate(res[1], patch, cv2.TM_CCOEFF_NORMED)
    assert ncc.max() < 0.3
    assert cv2.matchTemplate(res[0], patch, cv2.TM_CCOEFF_NORMED).max() > 0.99     # the probe can see a match


def test_a_fish_s_body_segment_follows_its_pose_and_clearance_is_the_sampled_distance():
    # the segment is cached per pose: moved, turned or bent, the fish answers for its new pose;
    # clearance against several fish at once is the brute-force distance between 12 points on each
    rng = np.random.default_rng(4)
    sp = SPECIES["sparus_aurata"]
    fishes = [make_fish(rng, i, sp, 150.0, 0.05) for i in range(4)]
    for f in fishes:
        f.centre, f.heading = rng.uniform(-200, 200, 3), float(rng.uniform(-3, 3))
    a = fishes[0]
    s0, f0, _ = a.segment_radius()
    a.centre = a.centre + [30.0, 0.0, 0.0]
    s1, f1, _ = a.segment_radius()
    assert np.allclose(s1 - s0, [30.0, 0.0, 0.0]) and np.allclose(f1 - f0, [30.0, 0.0, 0.0])
    a.heading += np.pi
    s2, f2, _ = a.segment_radius()
    assert np.allclose((s2 + f2) / 2, (s1 + f1) / 2) and np.allclose(s2 - f2, f1 - s1)

    def brute(p, q):
        t = np.arange(12) / 11.0
        pa = [p[0] + (p[1] - p[0]) * x for x in t]
        pb = [q[0] + (q[1] - q[0]) * x for x in t]
        return min(float(np.sqrt(((u - v) ** 2).sum())) for u in pa for v in pb)
    segs = [f.segment_radius() for f in fishes]
    want = all(brute(segs[0], q) >= 0.9 * (segs[0][2] + q[2]) for q in segs[1:])
    assert clear_of(a, fishes[1:]) == want
    a.centre = fishes[1].centre.copy()                 # on top of another: never clear
    assert not clear_of(a, fishes[1:])
    got = segment_distances(*a.segment_radius()[:2], *(np.array([s[i] for s in segs[1:]]) for i in (0, 1)))
    assert np.allclose(got, [brute(a.segment_radius(), q) for q in segs[1:]])


def test_stills_in_one_water_share_it_and_place_their_own_fish():
    """A camera held at one tank: the water (background, light, turbidity) is the visit's, the fish
    and the sensor noise each still's own."""
    rig = underwater_rig(**TINY)
    rng = np.random.default_rng(5)
    waters = [underwater_water(rng, rig, species="sparus_aurata", bubbles=0, particles=0) for _ in range(2)]
    same = [still_in(rng, rig, waters[0], n_fish=0) for _ in range(2)]
    other = still_in(rng, rig, waters[1], n_fish=0)
    noise = float(np.abs(same[0].left.astype(float) - same[1].left).mean())
    assert noise < 0.5 * float(np.abs(same[0].left.astype(float) - other.left).mean())
    assert not np.array_equal(same[0].left, same[1].left)             # the noise is each still's
    fish = [still_in(rng, rig, waters[0], n_fish=6, mean_length_cm=20.0, length_cv=0.1) for _ in range(2)]
    assert all(len(s.fish) == 6 for s in fish)
    assert all(abs(f.length_cm / 20.0 - 1) < 0.6 for s in fish for f in s.fish)
    centres = [np.array([f.snout_mm for f in s.fish]) for s in fish]
    assert not np.allclose(centres[0], centres[1])                    # placed anew
    drop = {"n_fish", "mean_length_cm", "length_cv"}
    assert {k: v for k, v in fish[0].conditions.items() if k not in drop} == \
        {k: v for k, v in same[0].conditions.items() if k not in drop}


def test_a_still_sets_only_its_own_fish():
    rig = underwater_rig(**TINY)
    rng = np.random.default_rng(6)
    water = underwater_water(rng, rig)
    with pytest.raises(ValueError, match="visibility_mm belong to the water"):
        still_in(rng, rig, water, n_fish=2, visibility_mm=3000.0)
    with pytest.raises(ValueError, match="n_fish must be >= 0"):
        still_in(rng, rig, water, n_fish=-1)
