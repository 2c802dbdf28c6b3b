"""The underwater per-pair pipeline (paper section 4): pre-processing, caudal-fin detection, fork
location, stereo pairing, snouts, 3-D association, post-filters and a quality score per fish.

Stages (``timings`` keys): ``illumination`` (pyramid, noise reduction, row compensation, water
distance), ``fins`` (fish regions, fork hypotheses at their ends, the template bank's, fish
silhouettes against a local background and the notches in their outlines), ``fork`` (forks
located at full resolution, eq. 13 scored there), ``stereo`` (fork pairing, forks seen in one
image looked for along their epipolar line in the other, triangulation), ``snout`` (profiles,
silhouettes' far ends and tips), ``associate`` (snout pairing in 3-D, each end checked along its
epipolar line, filters, score).

The score (0..1) is the fitted chance that the report is right (``vision.learned_score``, since
2026-12-03; before, and still in ``quality`` as ``hand_score``, the product of terms, each 1 when
that part of the measurement is as good as it gets and falling towards 0 as it becomes doubtful);
``FishMeasurement.quality`` holds the raw figures and the terms. Forks and snouts are placed by
the learned locators by default (``vision.fork_net``, ``vision.snout_net``).
Misplaced points show up as weak stereo evidence (NCC), epipolar residuals
(a snout or fork matched to the wrong structure does not triangulate cleanly), a weak snout edge,
an axis tilted towards the species' limit, or a fish too small in the image for pixel errors to
stay small against its length.

Where fish are lost, and what was tried (2026-12-02, bench/diag_underwater.py --scenes 40, and
bench/bench_survey_underwater.py --fish 200; seeds 0+ / 1000+). Of 75 / 97 fully visible fish,
proposals reach 54 / 57 (``vision.bodies``: faint fins and thin peduncles outside the regions,
touching fish merged), location keeps 34 / 37 (``vision.fork``: reef, net and faint fins), pairing
all of them, snouts 28 / 31, association 26 / 30, the post-filters 18 / 24. The post-filters take
a third of what the locator's improvements add: of the fish lost there after association, in 40
scenes ~half fall to ``min_score`` (products of small terms: ``t_fork_shape``, the residuals,
``t_fin``) and ~half to ``max_epipolar`` (several at 0.031-0.037), and every one of them was
placed within the bench's tolerance. Measured and left out, each locating or keeping more fish
and adding wrong reports too (bench, recall / precision; kept: 0.261 / 0.966 and 0.215 / 0.957):
arms refitted without outlying rows (``vision.fork``) 0.271 / 0.967, 0.220 / 0.918; the score's
epipolar residual scale grown to one step of the fork's grid 0.286 / 0.938, 0.230 / 0.906, with
``min_fill=0.5`` 0.276 / 0.937, 0.215 / 0.957; that with the refit and a 0.75x grid retried where a
hypothesis shows no fork 0.291 / 0.954, 0.215 / 0.938 (fork stage ~1.4x), with ``min_score=0.04``
0.276 / 0.952, 0.215 / 0.957; ``max_epipolar=0.04`` 0.271 / 0.935, 0.220 / 0.918; one location
pass, or the second keeping the first's fork where it shows none: more located, fewer found in the
40-scene diagnosis (the second pass's arm fit is what ``t_fork_shape`` trusts). The score, not the
locator, decides what the survey keeps, and it separates right from wrong poorly (Spearman 0.18
with the length error).

The keypoint net over the whole image (``vision.fish_keypoints``, ``Params.keypoints``, on)
proposes forks beside the classical proposers and a snout per fork: proposals stop being the
largest loss (38 fish of seeds 0-19: 13 -> 3 without one), recall rises on both bench sets at
precision >= 0.95 (figures in that module). The learned fork locator (``Params.fork_net``)
raises recall on every seed set but not at precision >= 0.95 on both bench sets with the packaged
keypoint net, so it is off; its figures are in ``vision.fork_net``. A keypoint net trained ~3x as
long (2026-12-03, not packaged; figures in ``vision.fish_keypoints``) with the classical locator
gains nothing: the locator drops what it proposes (seeds 0-39: 71 proposed, 39 located with either
net). With ``fork_net=True, kp_floor=0.4`` it reaches 0.345 / 0.961 / 2.49 % (seeds 0+) and 0.285 /
0.968 / 1.60 % (1000+) against today's 0.291 / 0.969 / 1.90 % and 0.240 / 0.962 / 1.45 %, but one
drawn fish of tests/vision/test_underwater.py then measures 1.51 % long (the learned locator places
less exactly), so neither is on. Keeping the net's own fork where the classical locator drops one
the net is sure of (conf >= 0.1-0.5, at the net's point or refined by ``vision.fork_net``) located
2-4 more of 71 on tuning seeds 200000-200039 and found none more (the post-filters drop them).
"""
from __future__ import annotations

import time

import cv2
import numpy as np

from vision import fish_keypoints, fork_net, snout_net
from vision.association import (
    View,
    camera_frame,
    match_forks,
    pair_snouts,
    patch_ncc,
    snout_search_range,
    transfer_forks,
    transfer_snouts,
)
from vision.bodies import body_ends, fish_masks
from vision.calib_file import StereoCalibration
from vision.fins import SPAN_OF_FL, Fins, bank_proposals, concat, fin_scores, suppress
from vision.fork import locate_forks, pyramid
from vision.illumination import water_distance
from vision.silhouettes import background_distance, components, outline_forks, silhouette_tips
from vision.silhouettes import fish_masks as outline_masks
from vision.snout import Snouts, find_snouts, refine_tips
from vision.survey_types import FishMeasurement, SurveySetup, plain_image
from vision.triangulation import triangulate_calibrated
from vision.underwater_params import Params
from vision.underwater_score import measurements


class _Clock:
    def __init__(self, timings: dict[str, float] | None):
        self.timings = timings
        self.t = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        if self.timings is not None:
            self.timings[stage] = self.timings.get(stage, 0.0) + now - self.t
        self.t = now


def proposals(img: np.ndarray, setup: SurveySetup, p: Params = Params(), clock: _Clock | None = None,
              trace: dict | None = None, bank: bool = True
              ) -> tuple[list[np.ndarray], Fins, list, tuple[float, float], object]:
    """The image pyramid, the fork hypotheses of every proposer (bodies' ends, eq. 13's bank,
    silhouettes, the keypoint net), the silhouettes' components, the working image's scale and the
    keypoint net's answer (None where it is off), for one image; ``bank`` False: without eq. 13's bank."""
    clock = _Clock(None) if clock is None else clock
    img = np.asarray(img)
    H, W = img.shape[:2]
    pyr = pyramid(img)
    k = min(int(np.floor(np.log2(W / p.work_width))), len(pyr) - 1) if W > p.work_width else 0
    scale = p.work_width / W if W > p.work_width else 1.0
    src = pyr[k]
    small = src if src.shape[1] == round(W * scale) else cv2.resize(
        src, (round(W * scale), round(H * scale)), interpolation=cv2.INTER_AREA)
    sx, sy = W / small.shape[1], H / small.shape[0]
    hyps, kp = Fins.empty(), None
    if p.keypoints:
        kp = fish_keypoints.detect(img, p.kp_width, p.kp_min_conf, p.kp_mirrored)
        hyps = concat([fish_keypoints.hypotheses(kp, off) for off in p.kp_offsets])
        clock.lap("keypoints")
    dist = None
    classical = p.kp_classical or not p.keypoints
    if p.row_regions and classical:
        dist = water_distance(small, setup.mi_ref, setup.c_ref)
        clock.lap("illumination")
        # two thresholds: a low one finds faint fish, a high one splits fish that touch at the low one
        found = [body_ends(m, sx, sy, p.min_fish_frac * small.shape[1])
                 for m in fish_masks(dist, p.mask_k, p.otsu_share)]
        ends, length = concat([f[0] for f in found]), np.concatenate([f[1] for f in found])
        # a region's end is the caudal peduncle when the fin is too faint to be in it (the region is
        # then ~0.87 of the fork length), or the lobe tips when it is not
        hyps = concat([hyps] + [_shifted(ends, length, off) for off in p.end_offsets])
    n_bank = int(round(p.bank_per_mpix * H * W / 1e6))
    if n_bank > 0 and classical and bank:
        if dist is None:
            dist = water_distance(small, setup.mi_ref, setup.c_ref)
            clock.lap("illumination")
        # a second proposer, eq. (13) over the working image: forks the bodies' ends miss (a fish
        # before reef or net, fish touching); each located like the others
        hyps = concat([hyps, bank_proposals(dist, sx, sy, n_bank, p.bank_levels, p.bank_stride, p.bank_keep)])
    comps = []
    if p.outlines:
        # a third, from silhouettes against the local background: the caudal notch as a convexity
        # defect of the outline, the outline's ends
        z = background_distance(small)[0]
        masks = outline_masks(z, p.outline_k)
        comps = components(masks)      # wanted for snouts and the score whichever proposes forks
        for m in masks if classical else []:
            f, ln = outline_forks(m, sx, sy, p.min_fish_frac * small.shape[1])
            notch = f.score > 1.0
            hyps = concat([hyps, f.take(np.flatnonzero(notch))]
                          + [_shifted(f.take(np.flatnonzero(~notch)), ln[~notch], off) for off in p.outline_ends])
    clock.lap("fins")
    if trace is not None:
        trace.setdefault("proposed", []).append(hyps.xy.copy())
        trace.setdefault("hypotheses", []).append((pyr, hyps))     # what the locator was given
    return pyr, hyps, comps, (sx, sy), kp


def _view(img: np.ndarray, setup: SurveySetup, p: Params, clock: _Clock, trace: dict | None = None,
          bank: bool = True):
    pyr, hyps, comps, scale, kp = proposals(img, setup, p, clock, trace, bank)
    located, fish, water, arm, conf = _locate(pyr, hyps, p)
    # the same fork from several hypotheses: the best (the net's confidence, else eq. 13's score)
    keep = suppress(located if conf is None else _scored(located, conf), p.max_fins, 0.1)
    fins = located.take(keep)
    clock.lap("fork")
    return View(pyr, fins, fish[keep], water[keep], arm[keep], comps, scale,
                None if conf is None else conf[keep]), kp


def _scored(f: Fins, score: np.ndarray) -> Fins:
    return Fins(f.xy, f.angle, f.span_px, score, f.polarity, f.body)


def _locate(pyr: list[np.ndarray], hyps: Fins, p: Params):
    """The forks at the hypotheses that show one: (fins, fish level, water level, arm RMS,
    confidence or None), the fins scored on eq. (13). Classical (``vision.fork``, twice: again from
    the fork) or learned (``vision.fork_net``, ``Params.fork_net``)."""
    if p.fork_net:
        located, fish, water, conf = fork_net.located(pyr, hyps, p.net_min_conf, p.upright, p.fin_window_upright)
        return located, fish, water, np.zeros(len(conf)), conf
    forks = locate_forks(pyr, hyps)
    forks = locate_forks(pyr, forks.fins.take(np.flatnonzero(forks.ok)))        # again, from the fork
    ok = np.flatnonzero(forks.ok)
    located = forks.fins.take(ok)
    located.score = fin_scores(pyr, located, upright=p.fin_window_upright)    # eq. (13), where the forks are
    return located, forks.fish_level[ok], forks.water_level[ok], forks.arm_rms[ok], None


def _transfer(calib, v1: View, v2: View, pairs, p: Params) -> tuple[View, View]:
    """Forks located in one image only: look for each in the other along its epipolar line
    (``association.transfer_forks``), locate it there, and add what is found to that view (a fork
    added to the right image is looked for back in the left too: that found one more fish of 200
    on the bench's seeds 1000+ than not, 2026-12-03)."""
    views = [v1, v2]
    for src, dst, Ps, Pd, used in ((0, 1, calib.P1, calib.P2, pairs.i), (1, 0, calib.P2, calib.P1, pairs.j)):
        lone = np.setdiff1d(np.arange(len(views[src].fins)), used)
        if len(lone) == 0:
            continue
        hyp = transfer_forks(Ps, Pd, views[src], views[dst], lone, p.near_mm, p.far_mm)
        v = views[dst]
        new, fish, water, arm, conf = _locate(v.pyr, hyp, p)
        if len(new) == 0:
            continue
        views[dst] = View(v.pyr, concat([v.fins, new]), np.vstack([v.fish_level, fish]),
                          np.vstack([v.water_level, water]), np.concatenate([v.arm_rms, arm]), v.comps, v.scale,
                          None if conf is None else np.concatenate([v.sure(), conf]))
    return views[0], views[1]


def _tips(v: View, f: Fins, pts: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The snout tip near each point (N, K, 2) in view v, for the forks f (rows of v ``idx``)."""
    N, K = pts.shape[:2]
    flat = pts.reshape(-1, 2)
    has = np.all(np.isfinite(flat), axis=1)
    found = np.zeros(N * K, bool)
    if has.any():
        r = np.repeat(np.arange(N), K)[has]
        dist = np.linalg.norm(flat[has] - f.xy[r], axis=1)
        water = v.water_level[idx][r]
        contrast = np.linalg.norm(v.fish_level[idx][r] - water, axis=1)
        tips, ok = refine_tips(v.pyr, flat[has], f.body_angle()[r], dist, water, contrast)
        flat = flat.copy()
        flat[has] = tips
        found[np.flatnonzero(has)] = ok
    return flat.reshape(N, K, 2), found.reshape(N, K)


def _shifted(fins: Fins, length: np.ndarray, frac: float) -> Fins:
    axes = np.column_stack((np.cos(fins.angle), np.sin(fins.angle)))
    return Fins(fins.xy + (frac * length)[:, None] * axes, fins.angle, 1.15 * fins.span_px, fins.score,
                fins.polarity, fins.body)


def measure_underwater(left: np.ndarray, right: np.ndarray, calib: StereoCalibration, setup: SurveySetup,
                       timings: dict[str, float] | None = None, params: Params = Params(),
                       trace: dict | None = None) -> list[FishMeasurement]:
    """Fish measured in one underwater pair (grey or BGR uint8, any size); [] when there are none.
    ``trace`` (diagnostics, bench/diag_underwater.py) receives each stage's points."""
    clock = _Clock(timings)
    left, right = plain_image(left), plain_image(right)
    if left.size == 0 or min(left.shape[:2]) < 32:
        return []
    v1, kp1 = _view(left, setup, params, clock, trace)
    # eq. 13's bank in the left view only (``Params.bank_right``): its forks are found in the right
    # one along their epipolar lines (``_transfer``)
    v2, kp2 = _view(right, setup, params, clock, trace, params.bank_right or not params.transfer)
    pairs = match_forks(calib, v1, v2, params.band_px)
    if params.transfer:
        v1, v2 = _transfer(calib, v1, v2, pairs, params)
        pairs = match_forks(calib, v1, v2, params.band_px)
    if trace is not None:
        trace["located"] = [v1.fins.xy.copy(), v2.fins.xy.copy()]
        trace["pairs"] = (v1.fins.xy[pairs.i].copy(), v2.fins.xy[pairs.j].copy())
    if len(pairs.i) == 0:
        clock.lap("stereo")
        return []
    f1, f2 = v1.fins.take(pairs.i), v2.fins.take(pairs.j)
    fork_mm, fork_res = triangulate_calibrated(calib, f1.xy, f2.xy)
    clock.lap("stereo")
    geo = setup.geometry
    lo_mm, hi_mm = 10 * geo.min_length_cm, 10 * geo.max_length_cm
    lo1, hi1 = snout_search_range(calib, fork_mm, f1.span_px, lo_mm, hi_mm, SPAN_OF_FL)
    scale21 = f2.span_px / f1.span_px
    sn = []
    for v, f, idx, lo, hi in ((v1, f1, pairs.i, lo1, hi1), (v2, f2, pairs.j, lo1 * scale21, hi1 * scale21)):
        sn.append(find_snouts(v.pyr, f.xy, f.body_angle(), 0.08 * f.span_px, v.fish_level[idx], v.water_level[idx],
                              lo, hi))
    if params.outlines:
        # the far end of the silhouette each fork belongs to, its tip refined on the image
        for c, (v, f, idx) in enumerate(((v1, f1, pairs.i), (v2, f2, pairs.j))):
            tips = silhouette_tips(v.comps, *v.scale, f.xy, f.body_angle(), f.span_px)
            tips, found = _tips(v, f, tips, idx)
            strength = np.where(found, 0.8, 0.4) * np.all(np.isfinite(tips), axis=2)
            sn[c] = Snouts(np.concatenate([sn[c].dist_px, np.linalg.norm(tips - f.xy[:, None], axis=2)], axis=1),
                           np.concatenate([sn[c].xy, tips], axis=1), np.concatenate([sn[c].strength, strength], axis=1))
    if params.keypoints and params.kp_snouts:
        # the snout the keypoint net pairs with the net's fork nearest each fork, its tip refined
        for c, (v, f, idx, kp) in enumerate(((v1, f1, pairs.i, kp1), (v2, f2, pairs.j, kp2))):
            _, tips, paired = fish_keypoints.near(kp, f.xy)
            tips, found = _tips(v, f, tips[:, None], idx)
            # (a snout only pointed at, no peak of the net's there, counts less)
            strength = np.where(found[:, 0], 0.9, 0.6) * np.where(paired > 0, 1.0, 0.6) * np.isfinite(tips[:, 0, 0])
            sn[c] = Snouts(np.concatenate([sn[c].dist_px, np.linalg.norm(tips - f.xy[:, None], axis=2)], axis=1),
                           np.concatenate([sn[c].xy, tips], axis=1),
                           np.concatenate([sn[c].strength, strength[:, None]], axis=1))
    left_sure = np.ones(sn[0].xy.shape[:2])       # the snout locator's confidence in each left candidate
    if params.snout_net:
        # each candidate moved to the tip the learned snout locator finds from it where it is sure,
        # dropped where it is not
        for c, f in enumerate((f1, f2)):
            tips, conf = snout_net.refine((v1, v2)[c].pyr, f.xy, sn[c].xy, upright=params.snout_crops_upright)
            if c == 0:
                left_sure = conf
            moved = np.where((conf >= params.snout_net_min)[..., None], tips, np.nan)
            if params.snout_to_edge:
                # the image's own edge owes nothing to the snouts the net was trained on (only the
                # tips kept: the others are dropped anyway)
                moved = _tips((v1, v2)[c], f, moved, (pairs.i, pairs.j)[c])[0]
            sn[c] = Snouts(np.linalg.norm(moved - f.xy[:, None], axis=2), moved, sn[c].strength)
    clock.lap("snout")
    up = np.asarray(setup.up_world if setup.up_world is not None else camera_frame(calib.P1)[1], float)
    up = up / np.linalg.norm(up)
    f_px, _ = camera_frame(calib.P1)
    depth = np.linalg.norm(fork_mm - (-np.linalg.solve(calib.P1[:, :3], calib.P1[:, 3])), axis=1)
    expected = f1.span_px * depth / f_px / SPAN_OF_FL             # the fin's size in mm, as a length
    gate = params.max_residual_px + 0.01 * f1.span_px / SPAN_OF_FL
    px1, s1, px2, s2 = sn[0].xy, sn[0].strength, sn[1].xy, sn[1].strength
    if trace is not None:
        trace["snouts"] = (px1.copy(), px2.copy())
    if params.transfer_snouts:
        # each left candidate also looked for along its epipolar line in the right image, within the
        # species' reach of the fork: a snout the right profile missed is still paired (kept only
        # where a tip is seen there: a point on a line is no snout by itself). Not the candidates
        # the snout locator doubts: a fish would rest on a doubtful snout anyway
        src = np.where((left_sure >= params.transfer_snout_min)[..., None], px1, np.nan)
        t2, tn = transfer_snouts(calib.P1, calib.P2, v1, v2, src, f1.body_angle(), f2.body_angle(),
                                 0.5 * f1.span_px, np.maximum(depth - 0.8 * expected, 1.0), depth + 0.8 * expected)
        t2, found = _tips(v2, f2, t2, pairs.j)
        px1, s1 = np.concatenate([px1, px1], axis=1), np.concatenate([s1, s1], axis=1)
        px2 = np.concatenate([px2, t2], axis=1)
        s2 = np.concatenate([s2, np.where(found, 0.9, 0.0) * s1[:, : t2.shape[1]] * (tn > 0)], axis=1)
    alike = patch_ncc(v1.pyr, v2.pyr, px1, px2, f1.angle, f2.angle, 0.5 * f1.span_px)
    ch = pair_snouts(calib, fork_mm, px1, s1, px2, s2, lo_mm, hi_mm, geo.max_tilt_deg, up, gate, expected, alike)
    # a right snout taken along the left one's epipolar line triangulates with no residual by
    # construction: its evidence is the views' likeness, not the residual
    view = np.ones(len(fork_mm))
    if params.transfer_snouts:
        same = np.all(np.abs(ch.px2[:, None] - t2) < 1e-9, axis=2)                      # (N, K)
        moved = same.any(axis=1)
        view = np.where(moved, np.clip((np.where(same, tn, 0).max(axis=1) - 0.5) / 0.4, 0, 1), 1.0)
    keep = ch.ok & np.all(np.isfinite(fork_mm), axis=1) & (fork_res <= gate)
    rows = np.flatnonzero(keep)
    fork_epi, snout_epi, fork_best, snout_best = _epipolar_checks(calib, v1, v2, pairs, f1, f2, ch, depth,
                                                                  expected, rows)
    if trace is not None:
        trace["associated"] = (f1.xy.copy(), f2.xy.copy(), ch.px1.copy(), ch.px2.copy(), keep.copy())
    sure = agree = np.ones(len(f1))
    if params.keypoints:
        (c1, a1), (c2, a2) = fish_keypoints.agreement(kp1, f1.xy, ch.px1), fish_keypoints.agreement(kp2, f2.xy, ch.px2)
        sure, agree = np.minimum(c1, c2), np.minimum(a1, a2)
    snout_sure = np.ones(len(f1))
    if params.snout_net and len(rows):
        # how sure the learned locator is of each chosen snout, in the worse view
        snout_sure[rows] = np.minimum(*(snout_net.refine(v.pyr, f.xy[rows], px[rows, None], 1,
                                                             params.snout_crops_upright)[1][:, 0]
                                        for v, f, px in ((v1, f1, ch.px1), (v2, f2, ch.px2))))
    out = measurements(rows, pairs, f1, f2, v1, v2, fork_mm, fork_res, ch, calib, geo, params,
                       left.shape[1], expected, view, (fork_epi, snout_epi, fork_best, snout_best), sure, agree,
                       snout_sure)
    clock.lap("associate")
    return out


def _epipolar_checks(calib, v1: View, v2: View, pairs, f1: Fins, f2: Fins, ch, depth: np.ndarray,
                     expected: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, ...]:
    """How far (px) each kept pair's fork and snout are from where the other image's best match
    along the epipolar line puts them: (fork, snout) in the worse view, then (fork, snout) in the
    better one. A fork or snout paired with the wrong structure on that line (another fin, a fin's
    edge) is not there. Only ``rows`` are looked for (the others are dropped anyway: 0 there)."""
    fork_epi, snout_epi = np.zeros(len(f1)), np.zeros(len(f1))
    fork_best, snout_best = np.zeros(len(f1)), np.zeros(len(f1))
    if len(rows) == 0:
        return fork_epi, snout_epi, fork_best, snout_best
    depth, expected = depth[rows], expected[rows]
    a, b = f1.take(rows), f2.take(rows)
    near, far = np.maximum(depth - 0.8 * expected, 1.0), depth + 0.8 * expected
    lo_d, hi_d = np.maximum(depth - 0.5 * expected, 1.0), depth + 0.5 * expected
    fwd = transfer_forks(calib.P1, calib.P2, v1, v2, pairs.i[rows], lo_d, hi_d)
    bwd = transfer_forks(calib.P2, calib.P1, v2, v1, pairs.j[rows], lo_d, hi_d)
    both = np.linalg.norm(fwd.xy - b.xy, axis=1), np.linalg.norm(bwd.xy - a.xy, axis=1)
    fork_epi[rows], fork_best[rows] = np.maximum(*both), np.minimum(*both)
    px1, px2 = ch.px1[rows], ch.px2[rows]
    s12, _ = transfer_snouts(calib.P1, calib.P2, v1, v2, px1[:, None], a.body_angle(), b.body_angle(),
                             0.5 * a.span_px, near, far)
    s21, _ = transfer_snouts(calib.P2, calib.P1, v2, v1, px2[:, None], b.body_angle(), a.body_angle(),
                             0.5 * b.span_px, near, far)
    both = np.linalg.norm(s12[:, 0] - px2, axis=1), np.linalg.norm(s21[:, 0] - px1, axis=1)
    snout_epi[rows], snout_best[rows] = np.maximum(*both), np.minimum(*both)
    return fork_epi, snout_epi, fork_best, snout_best
