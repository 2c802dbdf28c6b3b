"""The underwater per-pair pipeline end to end on pairs drawn through a known rig (flat fish with a
forked tail, independent of the renderer): fish it reports are where the drawn fish are, lengths
within 1.5 %, wild lengths score low; no fish, grey input, other image sizes."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from devices.sim.fish_scene import underwater_rig, underwater_scene
from devices.sim.stereo_rig import convergent_rig
from tests.vision.fish_drawing import underwater_pair, water
from vision import learned_score
from vision.survey import measure_pair
from vision.survey_types import FishGeometry, SurveySetup
from vision.underwater import Params, measure_underwater

SETUP = SurveySetup(up_world=(0.0, 0.0, 1.0))


def rig_of(size=(1280, 960), focal=1400.0):
    return convergent_rig(baseline_mm=400, crossing_mm=1200, focal_px=focal, image_size=size,
                          target=np.array([0, 1200, -1500.0]), forward=np.array([0, 1.0, 0]), up=np.array([0, 0, 1.0]))


def run(rig, seeds, setup=SETUP, grey=True):
    out = []
    for seed in seeds:
        left, right, truths = underwater_pair(np.random.default_rng(seed), rig, n_fish=3)
        if not grey:
            left, right = (np.dstack([im, im, (im * 0.6).astype(np.uint8)]) for im in (left, right))
        timings: dict[str, float] = {}
        fish = measure_pair(left, right, rig.calibration(), setup, timings)
        out.append((fish, truths, timings))
    return out


def placement(f, truths):
    """Relative 3-D error of a report against its nearest drawn fish: max(snout, fork) / length."""
    errs = [max(np.linalg.norm(f.snout_mm - s), np.linalg.norm(f.fork_mm - k)) / np.linalg.norm(s - k)
            for s, k, _, _ in truths]
    k = int(np.argmin(errs))
    return errs[k], f.length_cm * 10 / np.linalg.norm(truths[k][0] - truths[k][1]) - 1


@pytest.fixture(scope="module")
def results():
    return run(rig_of(), range(12))


def test_most_drawn_fish_are_measured_and_the_good_ones_to_1_5_percent(results):
    found = sum(len(f) for f, _, _ in results)
    drawn = sum(len(t) for _, t, _ in results)
    placed = [placement(f, t) for fish, t, _ in results for f in fish]
    good = np.array([abs(le) for e, le in placed if e < 0.03])
    assert len(good) >= 0.3 * drawn, (len(good), drawn)          # overlapping fish hide forks
    assert len(good) >= 0.7 * found
    # nine in ten, none past 2 %: over 60 pairs 95.5 % of 66 good reports are within 1.5 % and the
    # worst is 1.94 % (the fork locator of 2026-12-07; 97.3 % of 75 and 2.03 % with the one before);
    # 12 pairs (~14 good reports), so that one report over 1.5 % is not already a tenth
    assert np.mean(good < 0.015) >= 0.9 and good.max() < 0.02, np.sort(good)


@pytest.fixture(scope="module")
def sixty_drawn_pairs():
    rig = rig_of()
    return rig.calibration(), [underwater_pair(np.random.default_rng(seed), rig, n_fish=3) for seed in range(60)]


@pytest.mark.parametrize("edge", [False, True], ids=["default", "snout_to_edge"])
def test_snouts_at_the_edge_measure_drawn_fish_to_1_25_percent_for_nine_in_ten(sixty_drawn_pairs, edge):
    """Every well-placed report of 60 drawn pairs. The learned snout locator, trained on one
    renderer's snouts and looking at them at one scale, left one in ten of these fish over 1.41 %
    off (2026-12-06; on two outside testers' fish its snouts sat ~1 % of the length inside the fish);
    trained on every snout shape and looking again at a finer scale, 1.29 % (README, "Snout and fork
    shapes"). With each tip taken to the image's edge (``Params.snout_to_edge``) nine in ten are
    within 1.1 %. Since the keypoint net of 2026-12-07 (README, "The keypoint net retrained on reef")
    the default is as good: 1.09 % against the edge's 1.12 %. (Two tests: the suite's workers take
    one each.)"""
    calib, pairs = sixty_drawn_pairs
    placed = [placement(f, t) for left, right, t in pairs
              for f in measure_underwater(left, right, calib, SETUP, params=Params(snout_to_edge=edge))]
    good = np.array([le for e, le in placed if e < 0.03])
    assert len(good) >= 65
    assert abs(float(np.median(good))) < 0.005
    assert np.percentile(np.abs(good), 90) < 0.0125


def test_wild_lengths_score_below_good_ones(results):
    placed = [(placement(f, t), f.score) for fish, t, _ in results for f in fish]
    good = [s for (e, _), s in placed if e < 0.03]
    wild = [s for (e, le), s in placed if e >= 0.03 and abs(le) > 0.05]
    if wild:
        assert np.median(wild) < np.median(good)
    for fish, _, _ in results:
        for f in fish:
            assert 0.0 <= f.score <= 1.0
            assert {"stereo_ncc", "fork_residual_px", "snout_residual_px", "tilt_deg", "range_mm"} <= set(f.quality)
            assert f.fork_px.shape == (2, 2) and f.snout_px.shape == (2, 2)


def test_every_stage_is_timed(results):
    for _, _, timings in results:
        assert {"illumination", "fins", "fork", "stereo"} <= set(timings)
        assert all(v >= 0 for v in timings.values())


def test_open_water_gives_no_fish():
    rig = rig_of()
    rng = np.random.default_rng(9)
    imgs = [np.clip(water(960, 1280, rng), 0, 255).astype(np.uint8) for _ in range(2)]
    assert measure_pair(*imgs, rig.calibration(), SETUP) == []
    blank = np.zeros((960, 1280), np.uint8)
    assert measure_pair(blank, blank, rig.calibration(), SETUP) == []
    tiny = np.zeros((8, 8), np.uint8)
    assert measure_pair(tiny, tiny, rig.calibration(), SETUP) == []
    bgra = np.dstack([imgs[0]] * 3 + [np.full_like(imgs[0], 255)])
    assert measure_pair(bgra, bgra, rig.calibration(), SETUP) == []
    assert measure_pair(imgs[0][..., None], imgs[1][..., None], rig.calibration(), SETUP) == []


def test_colour_input_and_another_image_size():
    """BGR frames, and a 960x720 camera with a shorter focal length (the same scene, smaller):
    parameters scale with the image, nothing is fixed to 1280x960."""
    res = run(rig_of((960, 720), 1050.0), range(3), grey=False)
    placed = [placement(f, t) for fish, t, _ in res for f in fish]
    assert sum(e < 0.03 for e, _ in placed) >= 2


def test_species_limits_drop_lengths_outside_them(results):
    short = SurveySetup(up_world=(0.0, 0.0, 1.0), geometry=FishGeometry(min_length_cm=3, max_length_cm=12))
    for fish, _, _ in run(rig_of(), range(2), setup=short):
        assert all(f.length_cm <= 12 for f in fish)


def test_image_up_is_the_default_surface_normal():
    """up_world None: the left camera's image-up, world z for this level rig: same fish as with z."""
    a = run(rig_of(), [1])[0][0]
    b = run(rig_of(), [1], setup=SurveySetup())[0][0]
    assert len(a) == len(b)
    assert all(np.allclose(x.snout_mm, y.snout_mm) for x, y in zip(a, b, strict=True))


def test_each_reported_end_is_where_the_other_image_best_matches_it(results):
    """The epipolar post-filter: every fish reported has its fork and its snout within 3 % of its
    length of where the other image's best match along the epipolar line puts them, looked for
    from at least one of the views."""
    reported = [f for fish, _, _ in results for f in fish]
    assert reported
    for f in reported:
        q = f.quality
        assert max(q["fork_epi_best_px"], q["snout_epi_best_px"]) <= 0.03 * q["length_px"] + 1e-9
        assert q["fork_epi_best_px"] <= q["fork_epi_px"] and q["snout_epi_best_px"] <= q["snout_epi_px"]
        # measured, not left out: a search along the line in discrete steps never lands exactly
        assert q["fork_epi_px"] > 0 and q["snout_epi_px"] > 0
        assert 0.0 <= q["body_fill"] <= 1.0


def test_the_epipolar_check_from_either_view_keeps_what_both_views_keep_and_more():
    """Looked for from either view, the check drops a subset of what the check from both views
    drops (everything else the same): every fish kept by the stricter rule is kept (or its snout
    went to a better-scored fish, one fish per snout), and on rendered tanks some fish only the
    stricter rule drops are kept -- each one within 3 % of its length from one view's best match."""
    rig = underwater_rig()
    calib, setup = rig.calibration(), SurveySetup(up_world=(0.0, 0.0, 1.0))
    more = 0
    for seed in range(200003, 200009):         # 200006: a fish only the stricter rule drops
        scene = underwater_scene(np.random.default_rng(seed), rig)
        either = measure_underwater(scene.left, scene.right, calib, setup)
        both = measure_underwater(scene.left, scene.right, calib, setup, params=Params(epipolar_either=False))
        for f in both:
            assert any(np.allclose(f.snout_mm, g.snout_mm) and np.allclose(f.fork_mm, g.fork_mm) for g in either) \
                or any(np.linalg.norm(f.snout_mm - g.snout_mm) <= 0.03 * 10 * f.length_cm and g.score >= f.score
                       for g in either)
        more += len(either) - len(both)
        for f in either:
            assert f.quality["fork_epi_best_px"] <= 0.03 * f.quality["length_px"] + 1e-9
    assert more > 0


def test_fork_residual_filter_drops_exactly_the_fish_above_it():
    """``max_fork_residual_px``: at the median residual of the unfiltered fish, those above it go and
    the others are reported as before (none of these shared a snout with a dropped one)."""
    rig = rig_of()
    everyone = [f for seed in range(3) for f in measure_underwater(
        *underwater_pair(np.random.default_rng(seed), rig, n_fish=3)[:2], rig.calibration(), SETUP)]
    limit = float(np.median([f.quality["fork_residual_px"] for f in everyone]))
    assert any(f.quality["fork_residual_px"] > limit for f in everyone)         # some go, some stay
    for seed in range(3):
        left, right, _ = underwater_pair(np.random.default_rng(seed), rig, n_fish=3)
        before = measure_underwater(left, right, rig.calibration(), SETUP)
        after = measure_underwater(left, right, rig.calibration(), SETUP,
                                   params=replace(Params(), max_fork_residual_px=limit))
        kept = [f for f in before if f.quality["fork_residual_px"] <= limit]
        assert [f.snout_mm.tolist() for f in after] == [f.snout_mm.tolist() for f in kept]


def test_the_score_is_the_fitted_chance_of_the_reports_own_figures(results):
    """``learned_score``: each fish's score is ``vision.learned_score.chance`` of the figures it
    reports (a user can recompute it), every fish at least ``min_chance``; the hand-made product of
    terms is kept beside it as ``hand_score``."""
    reported = [f for fish, _, _ in results for f in fish]
    assert reported
    q = {k: np.array([f.quality[k] for f in reported]) for k in reported[0].quality}
    q["length_mm"] = np.array([10 * f.length_cm for f in reported])
    assert np.allclose(learned_score.chance(q), [f.score for f in reported], atol=1e-9)
    assert min(f.score for f in reported) >= Params().min_chance
    assert all(0 < f.quality["hand_score"] <= 1 for f in reported)


def test_a_lower_min_chance_keeps_every_fish_and_adds_only_less_likely_ones():
    rig = rig_of()
    for seed in range(3):
        left, right, _ = underwater_pair(np.random.default_rng(seed), rig, n_fish=3)
        strict = measure_underwater(left, right, rig.calibration(), SETUP)
        loose = measure_underwater(left, right, rig.calibration(), SETUP, params=replace(Params(), min_chance=0.0))
        kept = {tuple(f.snout_mm) for f in strict}
        assert kept <= {tuple(f.snout_mm) for f in loose}
        assert all(f.score < Params().min_chance for f in loose if tuple(f.snout_mm) not in kept)


def test_the_packaged_score_model_is_complete():
    m = learned_score.load()
    n = len(m["names"])
    assert n and set(m["names"]) <= set(learned_score.FEATURES)
    assert len(m["mean"]) == len(m["sd"]) == len(m["weights"]) == n
    # every feature varied in the data it was fitted on (a constant one would be dead weight)
    assert all(s > 1e-6 for s in m["sd"]) and np.all(np.isfinite(m["weights"]))


def test_no_fish_rests_on_a_fork_the_locator_is_less_sure_of_than_net_min_conf():
    """``net_min_conf``: with the score's filter off, every report's forks reach the bar in both
    views; a lower bar reports fish below the higher one (so the bar is what drops them)."""
    from devices.sim.fish_scene import underwater_scene
    low = 0
    # seed 8 has a fork 0.05-0.9 sure (the fork locator of 2026-12-07 is seldom unsure; seed 1's was a
    # right fork only eq. 13's bank proposed, before the bank proposed in the left view only)
    for seed in (0, 1, 2, 8):
        sc = underwater_scene(np.random.default_rng(seed))
        for bar in (0.05, 0.9):
            fish = measure_underwater(sc.left, sc.right, sc.rig.calibration(), SETUP,
                                      params=replace(Params(), min_chance=0.0, net_min_conf=bar))
            assert all(f.quality["fork_net_conf"] >= bar for f in fish)
            low += sum(f.quality["fork_net_conf"] < 0.9 for f in fish)
    assert low > 0


@pytest.mark.parametrize("bar", [0.0, 0.9])
def test_left_snouts_the_snout_locator_doubts_are_not_looked_for_on_the_right(monkeypatch, bar):
    """``transfer_snout_min``: the left snout candidates searched for along their epipolar lines are
    exactly those the learned snout locator (its first answer, on the left image) is that sure of
    (and, as every candidate kept, ``snout_net_min`` sure)."""
    from devices.sim.fish_scene import underwater_scene
    from vision import snout_net, underwater
    answers, searched = [], []
    real_refine, real_transfer = snout_net.refine, underwater.transfer_snouts

    def refine(pyr, fork_xy, pts, passes=2, upright=False):
        out = real_refine(pyr, fork_xy, pts, passes, upright)
        answers.append((pts.copy(), out[1].copy()))
        return out

    def transfer(P1, P2, left, right, px1, *a):
        searched.append(px1.copy())
        return real_transfer(P1, P2, left, right, px1, *a)

    monkeypatch.setattr(snout_net, "refine", refine)
    monkeypatch.setattr(underwater, "transfer_snouts", transfer)
    sc = underwater_scene(np.random.default_rng(2))      # 4 left candidates 0.5-0.9 sure
    measure_underwater(sc.left, sc.right, sc.rig.calibration(), SETUP, params=replace(Params(), transfer_snout_min=bar))
    pts, conf = answers[0]                       # the left image's candidates, before any is moved
    has = np.all(np.isfinite(pts), axis=2)
    kept = has & (conf >= Params().snout_net_min)
    wanted = kept & (conf >= bar)
    assert np.array_equal(np.all(np.isfinite(searched[0]), axis=2), wanted)
    assert kept.sum() > wanted.sum() or bar == 0.0      # at 0.9 some kept candidate was left out


@pytest.mark.parametrize("changes, right_has_bank", [({}, False), ({"bank_right": True}, True),
                                                      ({"transfer": False}, True)],
                         ids=["default", "bank_right", "no_transfer"])
def test_eq13s_bank_proposes_in_the_right_view_only_when_asked_or_nothing_is_transferred(changes, right_has_bank):
    """``bank_right``: by default the bank's hypotheses are the left view's only (its forks reach the
    right view along their epipolar lines); asked, or with the transfer off, both views have them.
    Judged against the same pair measured with the bank off everywhere."""
    sc = underwater_scene(np.random.default_rng(0))
    proposed = []
    for p in (replace(Params(), **changes), replace(Params(), bank_per_mpix=0.0, **changes)):
        trace: dict = {}
        measure_underwater(sc.left, sc.right, sc.rig.calibration(), SETUP, params=p, trace=trace)
        proposed.append(trace["proposed"])
    (left, right), (left_off, right_off) = proposed
    assert len(left) > len(left_off)
    if right_has_bank:
        assert len(right) > len(right_off)
    else:
        assert np.array_equal(right, right_off)
