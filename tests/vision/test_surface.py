"""Surface setup (nursery tank seen from above): per-image fish points and the stereo measurement,
on fish drawn from the contract's words (tests/vision/test_surface_drawing.py)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.vision.test_surface_drawing import (
    draw,
    edge_on,
    finish,
    floor,
    outline,
    place,
    reflection,
    stereo_tank,
    top_rig,
    world_fish,
)
from vision import surface_score
from vision.surface import (
    MAX_FORK_GAP,
    MIN_CHANCE,
    detect_fish,
    measure_surface,
    reported,
    surface_stages,
    up_direction,
)
from vision.survey import measure_pair
from vision.survey_types import FishGeometry, SurveySetup

SETUP = SurveySetup(setup="surface")


def _tank(fish, rng, glare=None, size=(1280, 960)):
    """One image: fish given as (snout (u, v), heading rad, length px[, darkness])."""
    img = floor(size, rng)
    for f in fish:
        draw(img, place(outline(f[2]), np.asarray(f[0], float), f[1]), *(f[3:] or ()))
    if glare is not None:
        reflection(img, *glare)
    return finish(img)


def _nearest(found, snout):
    return min(found, key=lambda f: np.linalg.norm(f.snout - snout) + 0 * f.length_px)


@pytest.mark.parametrize("heading_deg", range(0, 360, 45))
def test_snout_and_fork_found_at_every_heading(heading_deg):
    rng = np.random.default_rng(heading_deg)
    L = 150.0
    snout = np.array([640.0, 480.0])
    h = np.radians(heading_deg)
    img = _tank([(snout, h, L)], rng, glare=((200, 150), (70, 30)))
    found = detect_fish(img)
    assert len(found) == 1
    f = found[0]
    fork = snout + L * np.array([np.cos(h), np.sin(h)])
    assert np.linalg.norm(f.snout - snout) < 0.02 * L
    assert np.linalg.norm(f.fork - fork) < 0.02 * L           # the notch, not the lobe tips (+15 %)
    assert f.head_conf > 0.5 and f.fork_depth > 0.05


def test_head_decided_by_taper_when_the_tail_is_not_forked():
    rng = np.random.default_rng(3)
    img = floor(rng=rng)
    snout, L = np.array([400.0, 500.0]), 160.0
    draw(img, place(outline(L, lobe=0.05), snout, 0.0))      # lobes barely spread: no notch to see
    f, = detect_fish(finish(img))
    assert f.snout[0] < f.fork[0] and np.linalg.norm(f.snout - snout) < 0.02 * L


@pytest.mark.parametrize("heading_deg", [20, 110, 200, 290])
def test_edge_on_fin_fork_placed_from_the_fin_base_by_the_species_ratio(heading_deg):
    rng = np.random.default_rng(heading_deg)
    L, snout, h = 140.0, np.array([600.0, 450.0]), np.radians(heading_deg)
    img = floor(rng=rng)
    body, fin = edge_on(L)
    draw(img, place(body, snout, h))
    line = np.zeros(img.shape, np.uint8)
    ends = np.round(place(fin, snout, h)).astype(int)
    cv2.line(line, tuple(ends[0]), tuple(ends[1]), 255, 2, cv2.LINE_AA)
    img *= 1 - 0.25 * line.astype(np.float32) / 255                   # translucent, paler than the body
    img = finish(img)
    fork = snout + L * np.array([np.cos(h), np.sin(h)])
    f, = detect_fish(img, base_ratio=0.87)
    assert np.linalg.norm(f.snout - snout) < 0.02 * L
    assert np.linalg.norm(f.fork - fork) < 0.03 * L and not f.fork_seen
    g, = detect_fish(img)                                     # no ratio: the rear end of the fin
    assert np.linalg.norm(g.fork - (snout + 1.12 * L * np.array([np.cos(h), np.sin(h)]))) < 0.04 * L


@pytest.mark.parametrize("heading_deg", [35, 160, 250])
def test_a_peduncle_too_thin_for_the_outline_still_ends_the_body(heading_deg):
    # seen from above the body tapers into a caudal peduncle ~2.4 px wide: blur takes its edge below
    # the outline's level, but it is body (as dark) up to the fin base, where the edge-on fin (pale) begins
    rng = np.random.default_rng(heading_deg)
    L, snout, h = 150.0, np.array([560.0, 470.0]), np.radians(heading_deg)
    img = floor(rng=rng)
    x = np.linspace(0, 0.87 * L, 60)
    half = np.maximum(0.09 * L * np.sin(np.pi * np.clip(x / (0.8 * L), 0, 1) ** 0.7), 1.2)
    top = np.column_stack((x, half))
    draw(img, place(np.vstack([top, top[::-1] * [1, -1]]), snout, h))
    line = np.zeros(img.shape, np.uint8)
    ends = np.round(place(np.array([[0.87 * L, 0.0], [1.12 * L, 0.0]]), snout, h)).astype(int)
    cv2.line(line, tuple(ends[0]), tuple(ends[1]), 255, 1, cv2.LINE_AA)
    img *= 1 - 0.2 * line.astype(np.float32) / 255                 # the fin, edge-on and pale
    f, = detect_fish(finish(img), base_ratio=0.87)
    fork = snout + L * np.array([np.cos(h), np.sin(h)])
    assert np.linalg.norm(f.snout - snout) < 0.02 * L
    # the outline alone ends ~0.75 L: the species' ratio then put the fork at ~0.86 L
    assert np.linalg.norm(f.fork - fork) < 0.03 * L and not f.fork_seen


@pytest.mark.parametrize("heading_deg", [15, 100, 195, 280])
def test_a_caudal_fin_as_dark_as_the_peduncle_is_not_taken_for_body(heading_deg):
    # from above the edge-on caudal fin runs on from the peduncle as a thin strip as dark as the body
    # (one grey), 0.28 L long, its lobes 0.13 L past the fork: the body ends at the fin's base, not
    # at its tip (taken for the base, the fork placed from it by the ratio came out 1.33 L)
    rng = np.random.default_rng(heading_deg)
    L, snout, h = 150.0, np.array([620.0, 460.0]), np.radians(heading_deg)
    x = np.linspace(0, 0.85 * L, 40)
    half = 0.075 * L * np.sqrt(1 - x / (0.85 * L)) * (x / (0.85 * L)) ** 0.6 / 0.42 + 0.012 * L
    fin = [[0.85 * L, 0.007 * L], [1.13 * L, 0.004 * L]]                 # thinner than the peduncle's 0.012 L
    top = np.vstack([np.c_[x, half], fin])
    img = floor(rng=rng)
    draw(img, place(np.vstack([top, top[::-1] * [1, -1]]), snout, h))
    f, = detect_fish(finish(img), base_ratio=0.85)
    d = np.array([np.cos(h), np.sin(h)])
    assert np.linalg.norm(f.snout - snout) < 0.02 * L
    assert abs((f.base - snout) @ d - 0.85 * L) < 0.03 * L          # the fin's base
    assert np.linalg.norm(f.fork - (snout + L * d)) < 0.03 * L and not f.fork_seen


@pytest.mark.parametrize(("length", "fin_px"), [(90.0, 2), (140.0, 2), (140.0, 3)])
@pytest.mark.parametrize("heading_deg", [20, 110, 200, 290])
def test_an_edge_on_fin_drawn_as_a_dark_line_ends_the_body_at_its_base(heading_deg, fin_px, length):
    # the caudal fin edge-on as a line 2-3 px wide as dark as the body, from the fin base (0.87 L) to
    # the lobes' tips (1.12 L): thick enough to pass for a peduncle by its mass, so the body's end
    # (and the learned locator's) ran on along it and the fork came out 3-12 % long. A fin over half
    # as wide as the peduncle's end (0.06 L: 3 px at 90 px) is not told from it (README)
    rng = np.random.default_rng(heading_deg + fin_px)
    snout, h = np.array([640.0, 480.0]), np.radians(heading_deg)
    body, fin = edge_on(length)
    img = floor(rng=rng)
    draw(img, place(body, snout, h))
    mask = np.zeros(img.shape, np.float32)
    a, b = np.round(place(fin, snout, h) * 16).astype(int)
    cv2.line(mask, tuple(a), tuple(b), 1.0, fin_px, cv2.LINE_AA, 4)
    img *= 1 - 0.45 * mask
    f, = detect_fish(finish(img), base_ratio=0.87)
    d = np.array([np.cos(h), np.sin(h)])
    assert np.linalg.norm(f.snout - snout) < 0.02 * length
    assert np.linalg.norm(f.fork - (snout + length * d)) < 0.03 * length


def test_sizes_pale_and_dark_fish_under_the_lamp_gradient():
    rng = np.random.default_rng(5)
    fish = [((150, 150), 0.2, 60, 0.3), ((700, 200), 2.0, 220, 0.6), ((300, 700), -0.4, 120, 0.25),
            ((1000, 600), 1.2, 100, 0.5)]
    found = detect_fish(_tank(fish, rng))
    assert len(found) == 4
    for snout, _h, L, _ in fish:
        f = _nearest(found, np.asarray(snout, float))
        assert abs(f.length_px - L) < 0.03 * L + 1.0         # a pixel of blur on the 60 px fish


def test_pale_fish_over_a_dark_floor():
    rng = np.random.default_rng(6)
    img = floor(rng=rng, gradient=(70, 40))
    snout, L = np.array([300.0, 600.0]), 130.0
    draw(img, place(outline(L), snout, -0.7), darkness=-1.2)           # 2.2x the floor's brightness
    f, = detect_fish(finish(img))
    fork = snout + L * np.array([np.cos(-0.7), np.sin(-0.7)])
    assert np.linalg.norm(f.snout - snout) < 0.02 * L and np.linalg.norm(f.fork - fork) < 0.03 * L


def test_fish_cut_by_the_frame_edge_and_reflections_alone_are_not_reported():
    rng = np.random.default_rng(7)
    fish = [((-30, 300), 0.0, 150), ((1200, 800), 0.3, 150)]          # snout out; lobes out
    img = _tank(fish, rng, glare=((640, 480), (120, 40)))
    assert detect_fish(img) == []
    assert detect_fish(np.full((480, 640), 128, np.uint8)) == []
    assert detect_fish(np.zeros((480, 640, 3), np.uint8)) == []


def test_a_fish_next_to_a_reflection_keeps_its_points():
    rng = np.random.default_rng(8)
    snout, L = np.array([500.0, 400.0]), 150.0
    img = _tank([(snout, 0.0, L)], rng, glare=((600, 340), (80, 22), 0.0))   # the glare runs along its back
    found = detect_fish(img)
    assert len(found) == 1 and np.linalg.norm(found[0].snout - snout) < 0.03 * L


def _dark_patch(img, mask_drawer, darkness):
    m = np.zeros(img.shape[:2], np.float32)
    mask_drawer(m)
    img *= 1 - darkness * cv2.GaussianBlur(m, (0, 0), 2)


@pytest.mark.parametrize("seed", range(8))
def test_a_fish_grown_into_a_floor_stain_is_still_found(seed):
    """A dark stain on the floor ahead of the fish, joined to its snout by a faint smear: grown as
    one region with the fish, the stain the larger piece once the region is cut at its edge level.
    Every piece is tried, so the fish is found and the stain (a disc) is not a fish."""
    rng = np.random.default_rng(seed)
    img = floor(rng=rng)
    L, h = 120.0, rng.uniform(0, 2 * np.pi)
    snout = np.array([640.0, 480.0])
    d = np.array([np.cos(h), np.sin(h)])
    stain = snout - 90 * d
    _dark_patch(img, lambda m: cv2.circle(m, tuple(int(x) for x in stain), 55, 1.0, -1), 0.45)
    _dark_patch(img, lambda m: cv2.line(m, tuple(int(x) for x in stain), tuple(int(x) for x in snout), 1.0, 14), 0.11)
    draw(img, place(outline(L), snout, h))
    f, = detect_fish(finish(img))
    assert np.linalg.norm(f.snout - snout) < 0.03 * L and np.linalg.norm(f.fork - (snout + L * d)) < 0.03 * L


@pytest.mark.parametrize("length", [90.0, 130.0])
@pytest.mark.parametrize("heading_deg", range(0, 360, 30))
def test_a_slim_fish_is_not_cut_from_its_own_broad_tail(heading_deg, length):
    """A slim body (14 % as wide as long) behind whose thin peduncle the tail's lobes spread wider
    than the body: the tail has a thick core of its own, but is no second fish."""
    rng = np.random.default_rng(heading_deg)
    snout, h = np.array([640.0, 480.0]), np.radians(heading_deg)
    img = floor(rng=rng)
    draw(img, place(outline(length, width_frac=0.14, lobe=0.19), snout, h))
    f, = detect_fish(finish(img))
    fork = snout + length * np.array([np.cos(h), np.sin(h)])
    assert np.linalg.norm(f.snout - snout) < 0.02 * length and np.linalg.norm(f.fork - fork) < 0.02 * length


def test_touching_fish_are_split():
    rng = np.random.default_rng(9)
    L = 150.0
    fish = [((500, 400), 0.0, L), ((560, 417), np.pi / 2, L)]      # one noses the other's flank
    found = detect_fish(_tank(fish, rng))
    assert len(found) == 2
    for snout, *_ in fish:
        assert np.linalg.norm(_nearest(found, np.asarray(snout, float)).snout - snout) < 0.05 * L


def test_other_image_sizes():
    rng = np.random.default_rng(10)
    small = _tank([((100, 100), 0.5, 80)], rng, size=(400, 300))
    big = _tank([((600, 500), 2.5, 300)], rng, size=(1920, 1080))
    assert len(detect_fish(small)) == 1 and len(detect_fish(big)) == 1


FISH = [dict(length_mm=120, snout_xy=(-150, 50), heading=0.3, depth_mm=150),
        dict(length_mm=90, snout_xy=(100, -100), heading=2.5, depth_mm=250, tilt_deg=8),
        dict(length_mm=150, snout_xy=(0, 150), heading=-1.2, depth_mm=100),
        dict(length_mm=70, snout_xy=(250, 200), heading=np.pi, depth_mm=60)]


def test_stereo_fork_lengths_and_pixels():
    left, right, rig, truths = stereo_tank(np.random.default_rng(11), FISH, glare=((1000, 150), (60, 25)))
    found = measure_surface(left, right, rig.calibration(), SETUP, timings := {})
    assert set(timings) == {"prep", "detect", "stereo"}
    assert len(found) == len(truths)
    for s, k, spx, _kpx in truths:
        m = min(found, key=lambda m: np.linalg.norm(m.snout_mm - s))
        L = np.linalg.norm(s - k)
        assert np.linalg.norm(m.snout_mm - s) < 0.03 * L and np.linalg.norm(m.fork_mm - k) < 0.03 * L
        assert abs(m.length_cm * 10 - L) < 0.02 * L
        assert np.abs(m.snout_px - np.c_[spx[0], spx[1]].T).max() < 3
        assert 0.5 < m.score <= 1


def test_stereo_through_measure_pair_on_colour_and_grey():
    left, right, rig, _ = stereo_tank(np.random.default_rng(12), FISH[:2])
    calib = rig.calibration()
    grey = measure_pair(left, right, calib, SETUP)
    colour = measure_pair(cv2.cvtColor(left, cv2.COLOR_GRAY2BGR), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR),
                          calib, SETUP)
    assert len(grey) == 2 and [m.length_cm for m in grey] == pytest.approx([m.length_cm for m in colour])


def test_empty_tank_gives_no_fish():
    rig = top_rig()
    img = finish(floor(rng=np.random.default_rng(13)))
    assert measure_surface(img, img.copy(), rig.calibration(), SETUP) == []


def test_up_defaults_to_towards_the_cameras():
    up = up_direction(top_rig().calibration(), SETUP)
    assert up == pytest.approx([0, 0, 1], abs=0.01)
    assert up_direction(top_rig().calibration(), SurveySetup(setup="surface", up_world=(0, 0, 2))) == \
        pytest.approx([0, 0, 1])


def test_tilted_and_implausible_fish_dropped_and_tilt_lowers_the_score():
    fish = [dict(length_mm=120, snout_xy=(-150, 0), heading=0.0, depth_mm=150, tilt_deg=0),
            dict(length_mm=120, snout_xy=(100, -150), heading=0.0, depth_mm=150, tilt_deg=22),
            dict(length_mm=120, snout_xy=(0, 150), heading=0.0, depth_mm=150, tilt_deg=50)]
    left, right, rig, truths = stereo_tank(np.random.default_rng(14), fish)
    found = sorted(measure_surface(left, right, rig.calibration(), SETUP), key=lambda m: m.quality["tilt_deg"])
    assert len(found) == 2
    assert found[0].quality["tilt_deg"] < 3 and 18 < found[1].quality["tilt_deg"] < 26
    assert found[1].score < found[0].score
    narrow = SurveySetup(setup="surface", geometry=FishGeometry(min_length_cm=13, max_length_cm=40))
    assert measure_surface(left, right, rig.calibration(), narrow) == []


def test_the_score_is_the_fitted_chance_of_the_reports_own_figures():
    """Each fish's score is ``vision.surface_score.chance`` of the figures it reports (a user can
    recompute it); what is reported clears the chance's own floor and has the views' forks within
    MAX_FORK_GAP of each other."""
    fish = [dict(length_mm=120, snout_xy=(-150, 0), heading=0.0, depth_mm=150, tilt_deg=0),
            dict(length_mm=100, snout_xy=(100, -150), heading=1.0, depth_mm=200, tilt_deg=12),
            dict(length_mm=90, snout_xy=(0, 150), heading=2.5, depth_mm=100)]
    left, right, rig, _ = stereo_tank(np.random.default_rng(21), fish)
    measured = surface_stages(left, right, rig.calibration(), SETUP)["measured"]
    reported = measure_surface(left, right, rig.calibration(), SETUP)
    assert len(reported) == 3
    q = {k: np.array([m.quality[k] for m in measured]) for k in measured[0].quality}
    assert np.allclose(surface_score.chance(q), [m.score for m in measured], atol=1e-12)
    assert all(0 <= m.score <= 1 for m in measured)
    assert [m.snout_mm.tolist() for m in reported] == \
        [m.snout_mm.tolist() for m in measured if m.score >= MIN_CHANCE and m.quality["fork_gap"] < MAX_FORK_GAP]


@pytest.mark.parametrize("hand", [0.0, 0.001, 0.04, 1.0])
def test_a_report_rests_on_its_chance_and_the_views_forks_not_on_the_hand_made_product(hand):
    """The hand-made product no longer vetoes (its terms fell on right reports the fitted chance was
    sure of); the fitted chance's floor and the views' fork gap do, each on its own."""
    from vision.survey_types import FishMeasurement

    def fish(chance, gap):
        z = np.zeros(2)
        return FishMeasurement(np.zeros(3), np.ones(3), np.array([z, z]), np.array([z, z]), chance,
                               {"hand_score": hand, "fork_gap": gap})
    eps = 1e-9
    assert reported(fish(MIN_CHANCE, 0.0)) and reported(fish(1.0, MAX_FORK_GAP - eps))
    assert not reported(fish(MIN_CHANCE - eps, 0.0)) and not reported(fish(1.0, MAX_FORK_GAP))
    assert not reported(fish(0.0, 0.0)) and not reported(fish(1.0, 0.5))


def test_two_fish_on_one_epipolar_band_are_not_crossed():
    fish = [dict(length_mm=110, snout_xy=(-200, 0), heading=0.1, depth_mm=100),
            dict(length_mm=130, snout_xy=(80, 5), heading=0.1, depth_mm=300)]
    left, right, rig, truths = stereo_tank(np.random.default_rng(15), fish)
    found = measure_surface(left, right, rig.calibration(), SETUP)
    assert sorted(round(m.length_cm) for m in found) == [11, 13]


@pytest.mark.parametrize("shape", [(1, 1), (8, 8), (5, 300), (32, 32), (33, 47, 3), (480, 640)])
def test_frames_without_fish_of_any_size_give_no_fish(shape):
    rng = np.random.default_rng(16)
    calib = top_rig().calibration()
    for img in (np.zeros(shape, np.uint8), np.full(shape, 255, np.uint8),
                rng.integers(0, 256, shape).astype(np.uint8),
                ((rng.random(shape) < 0.01) * 255).astype(np.uint8)):
        assert measure_surface(img, img.copy(), calib, SETUP) == []


def test_a_fork_the_views_disagree_on_is_not_reported():
    """A lamp's sheen is view-dependent: it can cut a tail short in one view only. A fish whose right
    view ends 5 % of its length short of the left view's fork is not reported (its fork is in
    doubt); its neighbour, whole in both views, is."""
    rng = np.random.default_rng(17)
    rig = top_rig()
    imgs = [floor(rig.image_size, rng), floor(rig.image_size, rng, gradient=(190, 95))]
    whole = dict(length_mm=120, snout_xy=(-150, 50), heading=0.3, depth_mm=150)
    cut = dict(length_mm=120, snout_xy=(50, -150), heading=1.9, depth_mm=150)
    for f in (whole, cut):
        pts, _, _ = world_fish(**f)
        for view, (img, poly) in enumerate(zip(imgs, rig.project(pts), strict=True)):
            if f is cut and view == 1:     # the right view: the tail lost past 95 % of the length
                poly = poly[outline(f["length_mm"])[:, 0] <= 0.95 * f["length_mm"]]
            draw(img, poly)
    left, right = finish(imgs[0]), finish(imgs[1])
    found = measure_surface(left, right, rig.calibration(), SETUP)
    assert len(found) == 1
    s = world_fish(**whole)[1]
    assert np.linalg.norm(found[0].snout_mm - s) < 0.03 * whole["length_mm"]
    assert found[0].quality["q_fork_views"] > 0.5
    # the cut fish is paired and measured, and its fork term alone rules it out
    measured = surface_stages(left, right, rig.calibration(), SETUP)["measured"]
    doubt = [m for m in measured if np.linalg.norm(m.snout_mm - world_fish(**cut)[1]) < 0.05 * cut["length_mm"]]
    assert len(doubt) == 1 and doubt[0].quality["fork_gap"] > 0.04
    assert doubt[0].quality["q_fork_views"] < 0.05


def test_shadows_and_debris_on_a_known_floor_are_not_fish():
    """Seen from above under an oblique lamp, each fish casts a shadow of its own shape on the floor,
    stretched, and a stick lies there too: without the floor's distance they are reported as fish (a
    tester's 4 fish read as 7). With it (``floor_mm``: the floor 400 mm under the water, the cameras
    1000 mm over it), what lies on the floor is dropped and every fish found is kept."""
    lamp = np.array([45.0, 30.0])                       # the shadow's offset on the floor, mm
    shadows = [dict(f, depth_mm=400.0, length_mm=1.1 * f["length_mm"], tilt_deg=0.0, darkness=0.3,
                    snout_xy=tuple(np.asarray(f["snout_xy"]) + lamp + [0, 250])) for f in FISH[:3]]
    stick = [dict(length_mm=110.0, snout_xy=(-300.0, -250.0), heading=0.7, depth_mm=400.0, lobe=0.02,
                  width_frac=0.12, darkness=0.5)]
    fish = [dict(f, snout_xy=tuple(np.asarray(f["snout_xy"]) + [0, -150])) for f in FISH[:3]]
    left, right, rig, truths = stereo_tank(np.random.default_rng(21), fish + shadows + stick)
    calib = rig.calibration()
    real = truths[:3]

    def is_real(m):
        return any(np.linalg.norm(m.snout_mm - s) < 0.03 * np.linalg.norm(s - k) for s, k, _, _ in real)
    blind = measure_surface(left, right, calib, SETUP)
    assert sum(not is_real(m) for m in blind) >= 2, [m.snout_mm for m in blind]   # the phantoms this is about
    for up in (None, (0.0, 0.0, 1.0)):
        seen = measure_surface(left, right, calib, SurveySetup(setup="surface", floor_mm=1400.0, up_world=up))
        assert all(is_real(m) for m in seen) and len(seen) == sum(is_real(m) for m in blind) >= 1, up
        assert all(m.quality["floor_height_mm"] > 200 for m in seen)
    # the floor misplaced by 30 cm (above the fish's depths): a guess, not the tank -- nothing real is
    # kept that lies below it, but a floor far below everything drops nothing
    far = measure_surface(left, right, calib, SurveySetup(setup="surface", floor_mm=5000.0))
    assert len(far) == len(blind)
