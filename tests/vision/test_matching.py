"""Stereo matching along epipolar bands, on textured planes rendered through the paper's rig and on
hand-built pairs where one similarity term must decide."""
from __future__ import annotations

import numpy as np
import pytest

from devices.sim.stereo_rig import convergent_rig
from devices.sim.stereo_scene import random_texture, stripes, textured_plane
from vision.dlt import calibrate_camera
from vision.epipolar import epipolar_lines, fundamental_from_projections
from vision.matching import Reject, Weights, match_points, segments_by_offset, segments_by_range

W, H = 1280, 960
ROWS_F = np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]])     # rectified pair: the line of (u, v) is row v


@pytest.fixture(scope="module")
def rig():
    return convergent_rig()         # the paper's: axes crossing ~1 m ahead, 1280x960


def facing_plane(rig, rng, **kw):
    """A plane through the rig's crossing point, facing the cameras' midpoint."""
    c1, c2 = rig.centres
    return textured_plane(rig.P1, rig.P2, rig.image_size, rig.target, (c1 + c2) / 2 - rig.target, rng, **kw)


@pytest.fixture(scope="module")
def scene(rig):
    rng = np.random.default_rng(7)
    sc = facing_plane(rig, rng)
    pts1 = rng.uniform([0, 0], [W - 1, H - 1], (1000, 2))
    truth = sc.truth(pts1)
    visible = np.all((truth >= 8) & (truth <= [W - 9, H - 9]), axis=1)
    segments = segments_by_range(rig.P1, rig.P2, pts1, 900.0, 1400.0)       # the rig's working range
    return sc, pts1, truth, visible, segments, fundamental_from_projections(rig.P1, rig.P2)


def errors(result, truth):
    return np.linalg.norm(result.pts2 - truth, axis=1)


def test_dense_matches_land_within_a_fraction_of_a_pixel(scene):
    sc, pts1, truth, visible, segments, F = scene
    r = match_points(sc.img1, sc.img2, pts1, F, segments=segments)
    ok = r.valid & visible
    err = errors(r, truth)[ok]
    assert ok.sum() >= 0.95 * visible.sum()
    assert err.max() < 1.5                                     # no gross mismatch
    assert np.median(err) < 0.2 and np.percentile(err, 90) < 0.5
    assert np.all(r.line_px[r.valid] <= 1.0)                   # inside the +-1 px band
    assert np.all(r.scale[r.valid] == 1.0)
    # points whose match left image 2 have nothing to match: most are rejected, not invented
    assert (r.valid & ~visible).sum() <= 0.25 * (~visible).sum()


def test_trying_scales_follows_the_convergent_rigs_foreshortening(scene):
    sc, pts1, truth, visible, segments, F = scene
    plain = match_points(sc.img1, sc.img2, pts1, F, segments=segments)
    scaled = match_points(sc.img1, sc.img2, pts1, F, segments=segments, scales=(0.8, 1.0, 1.25))
    e_plain, e_scaled = errors(plain, truth), errors(scaled, truth)
    ok = plain.valid & scaled.valid & visible
    assert np.percentile(e_scaled[ok], 90) < 0.7 * np.percentile(e_plain[ok], 90)
    assert np.median(e_scaled[ok]) < 0.13
    # the right edge of image 1 is seen larger by camera 2, the left edge smaller
    right, left = ok & (pts1[:, 0] > 1100), ok & (pts1[:, 0] < 150)
    assert np.mean(scaled.scale[right] > 1) > 0.6 and np.mean(scaled.scale[left] < 1) > 0.4


def test_result_is_on_the_epipolar_line_and_inside_its_segment(scene):
    sc, pts1, truth, visible, segments, F = scene
    r = match_points(sc.img1, sc.img2, pts1[:200], F, segments=segments[:200], band_px=0)
    lines = epipolar_lines(F, pts1[:200])
    v = r.valid
    assert np.allclose(np.einsum("ij,ij->i", lines[v, :2], r.pts2[v]) + lines[v, 2], 0, atol=1e-6)
    seg = segments[:200][v]
    along = np.einsum("ij,ij->i", r.pts2[v] - seg[:, 0], seg[:, 1] - seg[:, 0])
    assert np.all(along >= -1e-6) and np.all(along <= np.einsum("ij,ij->i", *(2 * [seg[:, 1] - seg[:, 0]])))


def test_segments_by_range_bracket_the_true_depth(rig, scene):
    sc, pts1, truth, visible, segments, F = scene
    seg = segments_by_range(rig.P1, rig.P2, pts1, 900.0, 1400.0)
    # the truth lies between the two ends: its position along the segment is in [0, 1]
    d = seg[:, 1] - seg[:, 0]
    frac = np.einsum("ij,ij->i", truth - seg[:, 0], d) / np.einsum("ij,ij->i", d, d)
    assert np.all((frac > 0) & (frac < 1))
    narrow = segments_by_range(rig.P1, rig.P2, pts1, 2000.0, 2500.0)     # far behind the plane
    r = match_points(sc.img1, sc.img2, pts1[:100], F, segments=narrow[:100])
    assert np.all(errors(r, truth[:100])[r.valid] > 5)


def test_segments_by_range_in_a_left_handed_world(rig, scene):
    """A grid surveyed z-down: the DLT writes P1, P2 with positive depths and det(P[:, :3]) < 0. The
    search must still run in front of camera 1, on the same pixels as in the right-handed frame."""
    sc, pts1, truth, _, segments, _ = scene
    mirror = np.diag([1.0, 1.0, -1.0])
    grid = rig.target + 300.0 * np.random.default_rng(8).uniform(-1, 1, (60, 3))
    P1, P2 = (calibrate_camera(grid @ mirror, p) for p in rig.project(grid))
    assert np.linalg.det(P1[:, :3]) < 0 and np.linalg.det(P2[:, :3]) < 0
    left = segments_by_range(P1, P2, pts1, 900.0, 1400.0)
    np.testing.assert_allclose(left, segments, atol=1e-6)
    d = left[:, 1] - left[:, 0]
    frac = np.einsum("ij,ij->i", truth - left[:, 0], d) / np.einsum("ij,ij->i", d, d)
    assert np.all((frac > 0) & (frac < 1))


def test_segments_by_offset_start_at_the_points_own_coordinates():
    pts1 = np.array([[100.0, 50], [300, 200]])
    seg = segments_by_offset(pts1, ROWS_F, -30, 10)
    assert np.allclose(seg, [[[70, 50], [110, 50]], [[270, 200], [310, 200]]])


def test_repetitive_texture_is_rejected_as_ambiguous(rig):
    rng = np.random.default_rng(11)
    sc = facing_plane(rig, rng, texture=stripes((1200, 1500), period_texels=12))   # ~16 px period
    pts1 = rng.uniform([200, 150], [1000, 800], (300, 2))
    segments = segments_by_range(rig.P1, rig.P2, pts1, 900.0, 1400.0)
    r = match_points(sc.img1, sc.img2, pts1, fundamental_from_projections(rig.P1, rig.P2), segments=segments)
    assert np.mean(r.reason == Reject.AMBIGUOUS) > 0.9
    assert np.mean(r.valid) < 0.05


def _decoy_pair(rng):
    """Rectified pair: the true match 20 px left (a little sensor noise), and 60 px further a
    noiseless copy under 2.5x the light (zero-mean NCC cannot tell it from the truth)."""
    tex = 90 + 60 * random_texture((200, 640), rng)
    img1 = tex
    img2 = np.roll(tex, -20, axis=1) + rng.normal(0, 2.0, tex.shape)
    decoy = 2.5 * np.roll(tex, -80, axis=1) - 120
    img2[:, 215:265] = decoy[:, 215:265]
    pts1 = np.c_[rng.uniform(300, 320, 100), rng.uniform(30, 170, 100)]
    return img1.astype(np.float32), img2.astype(np.float32), pts1


def test_combined_score_prefers_the_truth_when_lighting_fools_ncc():
    img1, img2, pts1 = _decoy_pair(np.random.default_rng(2))
    segments = segments_by_offset(pts1, ROWS_F, -100, 0)
    ncc_only = match_points(img1, img2, pts1, ROWS_F, segments=segments, ambiguity_margin=0,
                            weights=Weights(ncc=1, line=0, mean=0, contrast=0))
    combined = match_points(img1, img2, pts1, ROWS_F, segments=segments)
    assert np.mean(np.abs(ncc_only.pts2[:, 0] - (pts1[:, 0] - 80)) < 0.5) > 0.9     # fooled
    at_truth = np.all(np.abs(combined.pts2 - (pts1 - [20, 0])) < 0.5, axis=1)
    assert np.mean(at_truth) > 0.95 and np.all(at_truth[combined.valid])
    assert np.mean(combined.valid) > 0.8      # the rest: the decoy came within the ambiguity margin


def test_ncc_is_the_zero_mean_form_invariant_to_gain_and_offset():
    rng = np.random.default_rng(4)
    tex = (255 * random_texture((200, 400), rng)).astype(np.float32)
    img2 = np.roll(tex, -7, axis=1)                                 # integer shift: exact windows
    pts1 = np.c_[rng.integers(60, 340, 50), rng.integers(20, 180, 50)].astype(float)
    segments = segments_by_offset(pts1, ROWS_F, -20, 0)
    ncc_only = Weights(ncc=1, line=0, mean=0, contrast=0)
    a = match_points(tex, img2, pts1, ROWS_F, segments=segments, weights=ncc_only)
    b = match_points(tex, 0.5 * img2 + 60, pts1, ROWS_F, segments=segments, weights=ncc_only)
    assert np.allclose(a.ncc, 1.0, atol=1e-4) and np.allclose(b.ncc, a.ncc, atol=1e-4)
    assert np.allclose(a.pts2, pts1 - [7, 0], atol=0.2) and np.allclose(b.pts2, a.pts2, atol=1e-3)
    # eq. (5) by hand, zero-mean, at a wrong position: the reported ncc of a forced candidate
    u, v = 200, 100
    w1 = tex[v - 5:v + 6, u - 5:u + 6]
    w2 = img2[v - 5:v + 6, u - 16:u - 5]
    z1, z2 = w1 - w1.mean(), w2 - w2.mean()
    forced = match_points(tex, img2, [[u, v]], ROWS_F, segments=[[[u - 11, v], [u - 11, v]]], band_px=0)
    assert forced.ncc[0] == pytest.approx((z1 * z2).sum() / np.sqrt((z1**2).sum() * (z2**2).sum()), abs=1e-4)


def test_sub_pixel_refinement_recovers_fractional_shifts():
    rng = np.random.default_rng(8)
    tex = (40 + 180 * random_texture((200, 600), rng)).astype(np.float32)
    shift = 12.3                                    # image 2 = image 1 moved 12.3 px left, resampled
    cols = np.arange(600, dtype=np.float32) + shift
    img2 = np.stack([np.interp(cols, np.arange(600), row) for row in tex])
    pts1 = np.c_[rng.uniform(100, 500, 200), rng.uniform(20, 180, 200)]
    r = match_points(tex, img2, pts1, ROWS_F, segments=segments_by_offset(pts1, ROWS_F, -30, 0))
    found = pts1[:, 0] - r.pts2[:, 0]
    assert r.valid.all() and np.median(np.abs(found - shift)) < 0.05 and np.abs(found - shift).max() < 0.2


def test_feature_candidates_pick_the_right_detection_and_refine_it(scene):
    sc, pts1, truth, visible, segments, F = scene
    rng = np.random.default_rng(3)
    pick = np.flatnonzero(visible)[:300]
    detected = truth[pick] + rng.normal(0, 0.7, (len(pick), 2))           # detector noise
    clutter = rng.uniform([0, 0], [W - 1, H - 1], (300, 2))
    cands = np.vstack([detected, clutter])
    order = rng.permutation(len(cands))
    r = match_points(sc.img1, sc.img2, pts1[pick], F, segments=segments[pick], candidates=cands[order],
                     band_px=3.0)
    chosen = cands[order][r.index]
    # the chosen detection is the point's own (or clutter that happens to lie on it)
    right = (order[r.index] == np.arange(len(pick))) | (np.linalg.norm(chosen - truth[pick], axis=1) < 1.5)
    assert np.mean(r.valid) > 0.9 and np.all(right[r.valid])
    assert np.mean(order[r.index][r.valid] == np.arange(len(pick))[r.valid]) > 0.95
    # refinement on the line beats the detector's own position
    assert np.median(errors(r, truth[pick])[r.valid]) < 0.5 * np.median(
        np.linalg.norm(detected - truth[pick], axis=1))
    kept = match_points(sc.img1, sc.img2, pts1[pick], F, segments=segments[pick], candidates=cands[order],
                        band_px=3.0, refine_px=0)
    assert np.array_equal(kept.pts2[kept.valid], cands[order][kept.index[kept.valid]])


def _twin_pair(rng):
    """Rectified pair where each point's window appears twice on its line in image 2: at -20 px and,
    as an exact copy, at -60 px (or 2 px below the line, for the line test)."""
    tex = (40 + 180 * random_texture((120, 400), rng)).astype(np.float32)
    img2 = np.roll(tex, -20, axis=1)
    pts1 = np.array([[200.0, 60.0]])
    return tex, img2, pts1


def test_size_and_orientation_break_a_tie_between_twin_fins():
    img1, img2, pts1 = _twin_pair(np.random.default_rng(6))
    img2[50:71, 130:151] = img1[50:71, 190:211]                  # the twin, 60 px left
    cands = np.array([[140.0, 60], [180, 60]])
    plain = match_points(img1, img2, pts1, ROWS_F, candidates=cands, band_px=1, refine_px=0)
    assert plain.reason[0] == Reject.AMBIGUOUS
    feats1 = np.array([[30.0, 0.2]])                             # fin size (px) and angle (rad)
    feats2 = np.array([[60.0, 1.8], [31.0, 0.25]])               # the twin is twice as big, turned
    r = match_points(img1, img2, pts1, ROWS_F, candidates=cands, features1=feats1, features2=feats2,
                     band_px=1, refine_px=0)
    assert r.valid[0] and r.index[0] == 1


def test_distance_to_the_line_breaks_a_tie():
    img1, img2, pts1 = _twin_pair(np.random.default_rng(6))
    img2[52:73, 130:151] = img1[50:71, 190:211]                  # the twin, 60 px left and 2 px low
    cands = np.array([[140.0, 62], [180, 60]])
    r = match_points(img1, img2, pts1, ROWS_F, candidates=cands, band_px=3, refine_px=0,
                     ambiguity_margin=0.02)
    assert r.valid[0] and r.index[0] == 1 and r.line_px[0] == 0
    flat = match_points(img1, img2, pts1, ROWS_F, candidates=cands, band_px=3, refine_px=0,
                        weights=Weights(line=0), ambiguity_margin=0.02)
    assert flat.reason[0] == Reject.AMBIGUOUS


def test_reasons_for_points_without_a_match():
    rng = np.random.default_rng(9)
    tex = (40 + 180 * random_texture((200, 400), rng)).astype(np.float32)
    tex[:, 300:] = 128.0                                           # a blank wall
    other = (40 + 180 * random_texture((200, 400), np.random.default_rng(10))).astype(np.float32)
    pts1 = np.array([[2.0, 100], [150, 100], [350, 100], [150, 100]])
    segments = np.array([[[100, 100], [140, 100]], [[-300, 100], [-200, 100]], [[300, 100], [340, 100]],
                         [[100, 100], [140, 100]]], float)
    r = match_points(tex, np.roll(tex, -20, axis=1), pts1[:3], ROWS_F, segments=segments[:3])
    assert list(r.reason) == [Reject.OUTSIDE, Reject.OUTSIDE, Reject.FLAT]
    assert np.isnan(r.pts2).all() and not r.valid.any()
    unrelated = match_points(tex, other, pts1[3:], ROWS_F, segments=segments[3:])
    assert unrelated.reason[0] == Reject.LOW_SCORE
    none_near = match_points(tex, tex, pts1[3:], ROWS_F, candidates=[[150.0, 140]])
    assert none_near.reason[0] == Reject.NO_CANDIDATE and none_near.index[0] == -1


def test_shapes_colour_and_empty_input(scene):
    sc, pts1, truth, visible, segments, F = scene
    empty = match_points(sc.img1, sc.img2, np.zeros((0, 2)), F)
    assert empty.pts2.shape == (0, 2) and empty.valid.shape == (0,)
    grey = match_points(sc.img1, sc.img2, pts1[:50], F, segments=segments[:50])
    colour = match_points(np.dstack([sc.img1] * 3), np.dstack([sc.img2] * 3), pts1[:50], F,
                          segments=segments[:50])
    assert np.allclose(grey.pts2, colour.pts2, equal_nan=True, atol=1e-3)
    with pytest.raises(ValueError, match="odd"):
        match_points(sc.img1, sc.img2, pts1[:2], F, patch=10)


def test_a_whole_line_scan_without_segments(scene):
    sc, pts1, truth, visible, segments, F = scene
    pick = np.flatnonzero(visible)[:40]
    r = match_points(sc.img1, sc.img2, pts1[pick], F)          # no working range: the whole line
    assert np.mean(r.valid) > 0.8 and np.all(errors(r, truth[pick])[r.valid] < 1.0)


def test_a_match_off_the_line_is_found_inside_the_band():
    # calibration error: image 2 sits 0.7 px lower than the epipolar geometry says
    rng = np.random.default_rng(12)
    tex = (40 + 180 * random_texture((240, 600), rng)).astype(np.float32)
    rows = np.arange(240, dtype=np.float32) - 0.7
    img2 = np.stack([np.interp(rows, np.arange(240), col) for col in np.roll(tex, -15, axis=1).T], axis=1)
    pts1 = np.c_[rng.uniform(100, 500, 200), rng.uniform(30, 210, 200)]
    segments = segments_by_offset(pts1, ROWS_F, -40, 0)
    truth = pts1 + [-15, 0.7]
    on_line = match_points(tex, img2, pts1, ROWS_F, segments=segments, band_px=0)
    band = match_points(tex, img2, pts1, ROWS_F, segments=segments, band_px=2)
    no_prior = match_points(tex, img2, pts1, ROWS_F, segments=segments, band_px=2, weights=Weights(line=0))
    assert np.median(errors(on_line, truth)[on_line.valid]) > 0.6      # held on the line: 0.7 px off
    # the line term is a prior that calibration is right to ~1 px: it pulls the estimate part way
    assert np.median(errors(band, truth)[band.valid]) < 0.8 * np.median(errors(on_line, truth)[on_line.valid])
    assert no_prior.valid.mean() > 0.95 and np.median(np.abs(no_prior.line_px[no_prior.valid] - 0.7)) < 0.1
    assert np.median(errors(no_prior, truth)[no_prior.valid]) < 0.12


def _exhaustive(img1, img2, pts, lo, hi, band, w):
    """Every whole-pixel candidate (u + t, v + b), lo <= t <= hi, |b| <= band, of integer points on a
    rectified pair scored by hand with the combined similarity; returns best score and position."""
    win2 = np.lib.stride_tricks.sliding_window_view(img2.astype(float), (11, 11))
    u, v = pts[:, 0].astype(int), pts[:, 1].astype(int)
    t, b = np.arange(lo, hi + 1), np.arange(-band, band + 1)
    cand = win2[(v[:, None, None] + b[:, None] - 5), (u[:, None, None] + t - 5)]     # (P, rows, cols, 11, 11)
    tmpl = np.stack([img1[y - 5:y + 6, x - 5:x + 6] for x, y in zip(u, v, strict=True)]).astype(float)
    z1 = tmpl - tmpl.mean(axis=(1, 2), keepdims=True)
    z2 = cand - cand.mean(axis=(3, 4), keepdims=True)
    ncc = np.einsum("pij,prcij->prc", z1, z2) / np.sqrt(
        (z1**2).sum(axis=(1, 2))[:, None, None] * (z2**2).sum(axis=(3, 4)))
    def ratio(a, c):
        return np.minimum(a, c) / np.maximum(a, c)
    mean = ratio(tmpl.mean(axis=(1, 2))[:, None, None], cand.mean(axis=(3, 4)))
    contrast = ratio(tmpl.std(axis=(1, 2))[:, None, None], cand.std(axis=(3, 4)))
    line = np.exp(-0.5 * b.astype(float) ** 2)[:, None]
    score = (w.ncc * ncc + w.line * line + w.mean * mean + w.contrast * contrast) / (
        w.ncc + w.line + w.mean + w.contrast)
    r, c = np.divmod(score.reshape(len(pts), -1).argmax(axis=1), len(t))
    return score.reshape(len(pts), -1).max(axis=1), np.c_[u + t[c], v + b[r]]


def test_coarse_to_fine_scan_finds_the_best_candidate_of_an_exhaustive_search():
    # the match sits 1 px below the line, on a band row the coarse pass (rows -2, 0, 2) skips; a weak
    # line prior lets it win there
    rng = np.random.default_rng(13)
    tex = (40 + 180 * random_texture((160, 420), rng)).astype(np.float32)
    img2 = (0.8 * np.roll(tex, (1, -25), axis=(0, 1)) + 20 + rng.normal(0, 3, tex.shape)).astype(np.float32)
    pts1 = np.c_[rng.integers(80, 400, 60), rng.integers(12, 148, 60)].astype(float)
    w = Weights(line=0.05)
    r = match_points(tex, img2, pts1, ROWS_F, segments=segments_by_offset(pts1, ROWS_F, -60, 0), band_px=3,
                     weights=w)
    best, at = _exhaustive(tex, img2, pts1, -60, 0, 3, w)
    assert np.allclose(r.score, best, atol=2e-4)                   # nothing better was skipped
    assert np.all(np.abs(r.pts2 - at) <= 0.5 + 1e-6)                # it is the best's sub-pixel peak
    assert np.mean(np.all(at == pts1 + [-25, 1], axis=1)) > 0.95 and r.valid.mean() > 0.95


def test_a_point_is_matched_alike_whatever_points_are_matched_with_it(scene):
    # points are scanned in chunks of like segment lengths: results must come back to their own rows
    sc, pts1, truth, visible, segments, F = scene
    rng = np.random.default_rng(14)
    shrink = rng.choice([0.1, 0.4, 1.0], len(pts1))[:, None, None]
    mixed = truth[:, None] + shrink * (segments - truth[:, None])          # still holding the truth
    together = match_points(sc.img1, sc.img2, pts1, F, segments=mixed)
    perm = rng.permutation(len(pts1))
    shuffled = match_points(sc.img1, sc.img2, pts1[perm], F, segments=mixed[perm])
    few = match_points(sc.img1, sc.img2, pts1[perm[:9]], F, segments=mixed[perm[:9]])
    for other, rows in ((shuffled, perm), (few, perm[:9])):
        assert np.array_equal(other.reason, together.reason[rows])
        assert np.allclose(other.pts2, together.pts2[rows], atol=1e-4, equal_nan=True)
        assert np.allclose(other.score, together.score[rows], atol=1e-5)
    assert together.valid[visible].mean() > 0.9
