"""Fish measured from above in a nursery tank (the paper's non-underwater setup, section 4.2, Fig. 6).

Per image (vision.surface_prep, .surface_regions, .surface_shape): noise reduction and a flat field
(the lamps' illumination divided out), region growing from seeds, each region's body axis, snout
tip, caudal-fork notch and midline points; which end is the head is decided by shape. Each region's
snout and body end are then moved to where two learned locators (vision.surface_nets) are sure
they are, when that is over 1.5 % of the length away (a pale head, a thin peduncle the region lost),
and its points placed again (``LEARNED_ENDS``).

Across the pair: a left fish and a right fish are the same fish when the right snout and fork lie on
the epipolar lines of the left ones (within a band that grows with the fish's size). Each view's
ends are carried into the other (vision.surface_stereo.ends_from_both_views): the snout further
out is taken, forks within 3.5 % of the length averaged. Each candidate
pairing is triangulated and checked in 3-D: fork length within the species' range
(``SurveySetup.geometry``), body axis within ``max_tilt_deg`` of the water surface. Pairs are taken
greedily, best first, one fish per region. The fish is then triangulated as a whole: a 3-D line is
fitted to its snout, fork and midline points (each midline point matched where its epipolar line
crosses the other view's midline) and the ends placed on that line where their rays pass, so one
end's depth error (a pixel of disparity is ~5 mm at 1 m) no longer becomes length or tilt.
When the two views disagree on which end is the head (the pairing fits with snout and fork swapped),
the view more sure of itself decides.

"Up" (the water surface's normal): ``SurveySetup.up_world`` when given; else, for this setup, the
direction from the tank towards the cameras, i.e. minus the mean of the two optical axes: cameras
over a tank look down, so the image-up of the underwater default would lie in the water surface.

Score (0..1): the fitted chance the report is right (``vision.surface_score``), from the figures
kept in ``quality``. A fish is reported when the fitted chance is at least MIN_CHANCE and the views'
forks are less than MAX_FORK_GAP of the length apart (the hand-made score, the product of the terms
kept in ``quality`` as ``hand_score``, vetoed too until 2026-12-07). The hand-made terms: epipolar
residual of snout and fork
(``q_epipolar``), axis tilt against the surface (``q_tilt``), straightness of the body through the
intermediate points in the left view (``q_straight``; a fish bent sideways has a fork length
shorter than its body),
head/tail confidence (``q_head``), the caudal fork found as a notch in both views (``q_fork``: 1; in
neither, placed from the fin base: 0.8; in one only: 0.6), the right view's own fork against the
place the left fork's epipolar line gives it (``q_fork_views``, Gaussian in 2 % of the length: the
views disagree where one of them cuts the tail short), the outline free of lamp reflections
(``q_glare``), and left/right agreement of the apparent length (``q_views``). Fork length is the
straight 3-D snout-fork distance (the contract); the length along the body through the
intermediate points (the 3-D length scaled by the view's bend) is kept as ``body_mm``.
"""
from __future__ import annotations

import time

import numpy as np

from vision import surface_nets, surface_score
from vision.calib_file import StereoCalibration
from vision.epipolar import fundamental_from_projections
from vision.surface_prep import contrast_map
from vision.surface_regions import Region, RegionParams, find_regions
from vision.surface_shape import Fish2D, analyse
from vision.surface_stereo import (
    body_crossings,
    candidate_pairs,
    ends_from_both_views,
    ends_on_axis,
    fit_axis,
    fit_axis_robust,
    refine,
)
from vision.survey_types import FishMeasurement, SurveySetup
from vision.triangulation import camera_centre, triangulate_calibrated

# The hand-made product (``hand_score``) vetoed reports under 0.05 until 2026-12-07 (thirty-eighth
# session): it fell on right reports the fitted chance was sure of (tuning tanks 7000-7039: 15,
# chances 0.11-0.83, most for a fork gap of 2-9 % or a weak match); only its fork term vetoes now
MAX_FORK_GAP = 0.04     # the views' forks this far apart (per unit of length) or more: one of them lost
                        # its tail and nothing tells which; not reported
MIN_CHANCE = 0.2        # nor is a report the fitted score gives under this chance of being right
                        # (0.1 with the product's veto; 0.02 before 2026-12-07): figures unlike any
                        # rendered fish's (a real chessboard's square read as a 3.7 cm fish: chance ~0;
                        # an office's dark shape read as a 7.9 cm fish at 0.03). With these two floors
                        # instead of the product's veto, rendered tanks 8000-8209 / 8210-8419: recall
                        # 0.411 / 0.439 -> 0.432 / 0.456 at precision 0.900 / 0.903 -> 0.900 / 0.894
                        # (0.3: 0.423 / 0.455 at 0.904 / 0.908, but a fish pitched 22 deg, chance 0.24,
                        # is dropped: the renderer's fish pitch at most 12 deg)
# the right view's own fork against the left fork's epipolar line, per unit of length: the scale of
# q_fork_views. 0.06 -> 0.02 on the bench's 30 tanks: reports 86 -> 65, recall 0.139 -> 0.130,
# precision 0.349 -> 0.431 (image 0.663 -> 0.800): a fork 3.5 % of the length off is not reported
FORK_GAP = 0.02
MIN_SIDE_PX = 32        # an image smaller than this either way holds no measurable fish
# With the floor's distance known (``SurveySetup.floor_mm``), a "fish" whose snout and fork both lie
# within this of it (mm, or this share of its length if more) is something on the floor: a fish's
# shadow under an oblique lamp (a tester's 4 fish were reported as 7, the shadows 10-20 % longer
# than their fish) or debris (a stick, a leaf). A fish resting upright on the floor has its axis
# ~15 % of its length above it.
FLOOR_CLEARANCE_MM = 10.0
FLOOR_CLEARANCE = 0.05
# each region's snout and body end moved to the learned locators' (vision.surface_nets) where they
# are sure; off, the regions' own (tools/surface_net_data.py makes the nets' hypotheses so)
LEARNED_ENDS = True
AXIS_TILT_EXCESS = 3.0   # deg: a fitted line tilted this much more than the ends' own triangulation
                         # went astray (midline points matched on the wrong part of the body, a fish
                         # along the epipolar lines) and the ends' own 3-D points are kept instead


def _tick(timings, stage, t0):
    if timings is not None:
        timings[stage] = timings.get(stage, 0.0) + time.perf_counter() - t0
    return time.perf_counter()


DEFAULT_PARAMS = RegionParams()


def _fish_in(img: np.ndarray, c, params: RegionParams, base_ratio: float | None) -> list[Fish2D]:
    found = [(r, analyse(r, base_ratio)) for r in find_regions(c, params)]
    found = [(r, f) for r, f in found if f is not None and f.elongation >= params.min_slender]
    if LEARNED_ENDS and found:
        found = _learned_ends(img, found, base_ratio)
    found = [f for _, f in found]
    # one fish seen as two regions (a dark body and a light one, under a glint): keep the longer
    found.sort(key=lambda f: -f.length_px)
    kept: list[Fish2D] = []
    for f in found:
        if not any(min(np.linalg.norm(f.snout - g.snout), np.linalg.norm(f.snout - g.fork)) < 0.15 * g.length_px
                   and min(np.linalg.norm(f.fork - g.fork), np.linalg.norm(f.fork - g.snout)) < 0.15 * g.length_px
                   for g in kept):
            kept.append(f)
    return kept


def _learned_ends(img: np.ndarray, found: list[tuple[Region, Fish2D]], base_ratio: float | None
                  ) -> list[tuple[Region, Fish2D]]:
    """Each region's snout and body end moved to the learned locators' (``vision.surface_nets``)
    where they are sure and move it by more than ``MIN_MOVE`` of the length, the fish's other points
    placed again from them (``analyse``: a body end is not taken out along a dark caudal fin)."""
    fish = [f for _, f in found]
    s, cs, b, cb = surface_nets.refine_ends(img, np.array([f.snout for f in fish]), np.array([f.base for f in fish]),
                                            np.array([f.fork for f in fish]), np.array([f.length_px for f in fish]))
    out = []
    for k, (r, f) in enumerate(found):
        move = surface_nets.MIN_MOVE * f.length_px
        sure_s = cs[k] >= surface_nets.MIN_CONF and np.linalg.norm(s[k] - f.snout) > move
        # a notch seen is the fork: the body's end only spaces the midline then, and is left be
        sure_b = not f.fork_seen and cb[k] >= surface_nets.MIN_CONF and np.linalg.norm(b[k] - f.base) > move
        if sure_s or sure_b:
            g = analyse(r, base_ratio, s[k] if sure_s else None, b[k] if sure_b else None)
            if g is not None:
                f = g
                f.snout_conf = float(cs[k]) if sure_s else 0.0
                f.base_conf = float(cb[k]) if sure_b else 0.0
        out.append((r, f))
    return out


def detect_fish(img: np.ndarray, params: RegionParams = DEFAULT_PARAMS,
                base_ratio: float | None = None) -> list[Fish2D]:
    """Fish found in one image seen from above: front, rear and intermediate points of each."""
    if min(np.shape(img)[:2]) < MIN_SIDE_PX:
        return []
    return _fish_in(img, contrast_map(img), params, base_ratio)


def up_direction(calib: StereoCalibration, setup: SurveySetup) -> np.ndarray:
    """Unit normal of the water surface in world mm (see module docstring)."""
    if setup.up_world is not None:
        up = np.asarray(setup.up_world, float)
        return up / np.linalg.norm(up)
    view = np.zeros(3)
    for P in (calib.P1, calib.P2):
        M = np.asarray(P, float)[:, :3]
        view += np.sign(np.linalg.det(M)) * M[2] / np.linalg.norm(M[2])
    return -view / np.linalg.norm(view)


def _orient(a: Fish2D, b: Fish2D, swapped: bool):
    """Left and right points (2 + K, 2) [snout, fork, intermediate...] of a pair after settling which
    end is the head, and the confidence of that decision."""
    pa = np.vstack([a.snout, a.fork, a.mid])
    pb = np.vstack([b.snout, b.fork, b.mid])
    flip = np.r_[1, 0, np.arange(len(b.mid) + 1, 1, -1)]       # the other end is the head
    if not swapped:
        return pa, pb, 1 - (1 - a.head_conf) * (1 - b.head_conf)
    if a.head_conf >= b.head_conf:
        return pa, pb[flip], a.head_conf - b.head_conf
    return pa[flip], pb, b.head_conf - a.head_conf


def _solids(calib, setup: SurveySetup, up, sets: list[tuple[np.ndarray, np.ndarray]]):
    """For each (pts1, pts2) of one fish: its triangulated points and residuals, snout-fork length
    and tilt, or None when the species geometry rules the pairing out. One triangulation call for
    all the fish (its set-up costs more than a fish's points)."""
    if not sets:
        return []
    X, res = triangulate_calibrated(calib, np.vstack([a for a, _ in sets]), np.vstack([b for _, b in sets]))
    g = setup.geometry
    out, k = [], 0
    for a, _ in sets:
        Xi, ri = X[k:k + len(a)], res[k:k + len(a)]
        k += len(a)
        length_mm = float(np.linalg.norm(Xi[0] - Xi[1]))
        ok = np.all(np.isfinite(Xi)) and 10 * g.min_length_cm <= length_mm <= 10 * g.max_length_cm
        tilt = _tilt(Xi[0] - Xi[1], up) if ok else 90.0
        out.append((Xi, ri, length_mm, tilt) if ok and tilt <= g.max_tilt_deg else None)
    return out


def _on_axis(calib, up, solid, pts1, pts2, matched):
    """The fish triangulated as a whole: a 3-D line fitted to its snout, fork and midline points,
    the ends placed on it where their rays pass (see vision.surface_stereo.ends_on_axis)."""
    X, res, own_length, own_tilt = solid
    # the midline points matched where the other view's midline crosses their epipolar lines; the
    # others (a body along the lines) are only the other view's own midline at the same fraction
    c, d = fit_axis_robust(X[matched]) if matched.sum() >= 5 else fit_axis(X)
    S, K = ends_on_axis(calib, c, d, np.array([pts1[0], pts1[1]]), np.array([pts2[0], pts2[1]]))
    tilt = _tilt(S - K, up)
    if tilt - own_tilt > AXIS_TILT_EXCESS:
        return solid                 # the line went astray: the ends as their own pixels place them
    length_mm = float(np.linalg.norm(S - K))
    X = X.copy()
    X[0], X[1] = S, K
    return X, res, length_mm, tilt


def _tilt(axis: np.ndarray, up: np.ndarray) -> float:
    """Degrees between a 3-D axis and the water surface."""
    return float(np.degrees(np.arcsin(min(abs(axis @ up) / max(float(np.linalg.norm(axis)), 1e-9), 1.0))))


def _measure(setup: SurveySetup, a: Fish2D, b: Fish2D, pts1, pts2, head, solid, ncc,
             fork_gap: float) -> FishMeasurement:
    X, res, length_mm, tilt = solid
    S, K = X[0], X[1]
    g = setup.geometry
    # bend from the left view (the midline points' depths are the noisiest numbers of the fish)
    mids = pts1[2:]       # 5 of them: between close midline points the slices' noise reads as bend
    chain = np.vstack([pts1[0], mids[np.round(np.linspace(0, len(mids) - 1, 5)).astype(int)], pts1[1]])
    along = np.linalg.norm(np.diff(chain, axis=0), axis=1).sum()
    straight = float(np.linalg.norm(pts1[0] - pts1[1]) / max(along, 1e-9))
    body_mm = length_mm / max(straight, 1e-9)
    epi = float(np.sqrt(np.mean(res[:2] ** 2)))
    views = min(a.length_px, b.length_px) / max(a.length_px, b.length_px)
    q = {
        "q_epipolar": float(np.exp(-(epi / (0.75 + 0.005 * a.length_px)) ** 2)),
        "q_tilt": float(np.exp(-(tilt / (g.max_tilt_deg / 2.5)) ** 2)),     # fish swim level
        "q_straight": float(np.clip((straight - 0.9) / 0.1, 0, 1)) ** 0.5,
        "q_head": float(0.5 + 0.5 * np.clip(head, 0, 1)),
        "q_fork": 1.0 if a.fork_seen and b.fork_seen else (0.6 if a.fork_seen or b.fork_seen else 0.8),
        "q_fork_views": float(np.exp(-(fork_gap / FORK_GAP) ** 2)),
        "q_glare": float(np.clip(1 - 2 * max(a.glare, b.glare), 0, 1)),
        "q_views": float(np.clip((views - 0.6) / 0.3, 0, 1)),
        "q_match": float(np.clip(np.nan_to_num(ncc, nan=0.6).min(), 0.5, 1.0)) * 2 - 1,
    }
    hand = float(np.prod(list(q.values())))
    q.update({"epipolar_px": epi, "mid_epipolar_px": float(np.sqrt(np.mean(res[2:] ** 2))), "tilt_deg": tilt,
              "body_mm": body_mm, "straightness": straight, "head_conf": float(head),
              "ncc_snout": float(np.nan_to_num(ncc[0])), "ncc_fork": float(np.nan_to_num(ncc[1])),
              "fork_depth": float(min(a.fork_depth, b.fork_depth)), "length_px": a.length_px,
              "fork_gap": fork_gap, "net_snout_conf": min(a.snout_conf, b.snout_conf),
              "net_base_conf": min(a.base_conf, b.base_conf), "hand_score": hand})
    return FishMeasurement(S, K, np.array([pts1[0], pts2[0]]), np.array([pts1[1], pts2[1]]), hand, q)


def _patch(fish: list[Fish2D]) -> int:
    """Correlation window side: a tenth of the typical fish length, odd, 9..41 px (on renders an
    eighth to a fifth matched the snout a little worse in depth)."""
    n = int(np.clip(0.1 * np.median([f.length_px for f in fish]), 9, 41))
    return n | 1


def measure_surface(left: np.ndarray, right: np.ndarray, calib: StereoCalibration, setup: SurveySetup,
                    timings: dict[str, float] | None = None) -> list[FishMeasurement]:
    """Fish measured in one pair seen from above (see module docstring). Never raises on a frame
    without fish: returns []."""
    measured = surface_stages(left, right, calib, setup, timings)["measured"]
    return [m for m in measured if reported(m) and not on_floor(m, calib, setup)]


def on_floor(m: FishMeasurement, calib: StereoCalibration, setup: SurveySetup) -> bool:
    """Whether both ends lie on the tank floor (``SurveySetup.floor_mm`` below camera 1 along "up"):
    not a fish. Their height above it is kept in ``quality`` (``floor_height_mm``, the higher end)."""
    if setup.floor_mm is None:
        return False
    up = up_direction(calib, setup)
    centre = camera_centre(np.asarray(calib.P1, float))
    height = max(float((np.asarray(x) - centre) @ up) + setup.floor_mm for x in (m.snout_mm, m.fork_mm))
    m.quality["floor_height_mm"] = height
    return height < max(FLOOR_CLEARANCE_MM, FLOOR_CLEARANCE * 10.0 * m.length_cm)


def reported(m: FishMeasurement) -> bool:
    """Whether a measured fish is reported: the fitted chance clears its floor and the views' forks
    agree."""
    return m.quality["fork_gap"] < MAX_FORK_GAP and m.score >= MIN_CHANCE


def surface_stages(left: np.ndarray, right: np.ndarray, calib: StereoCalibration, setup: SurveySetup,
                   timings: dict[str, float] | None = None) -> dict:
    """The pipeline's intermediate results, for diagnosis (bench/diag_surface.py): ``left`` and
    ``right`` (Fish2D per view), ``pairs`` ((left index, right index) taken), ``measured`` (every
    paired fish's FishMeasurement, before the reporting cut) and ``measured_pair`` (its index in ``pairs``)."""
    t0 = time.perf_counter()
    out: dict = {"left": [], "right": [], "pairs": [], "measured": [], "measured_pair": []}
    if min(np.shape(left)[:2] + np.shape(right)[:2]) < MIN_SIDE_PX:
        return out
    cl, cr = contrast_map(left), contrast_map(right)
    t0 = _tick(timings, "prep", t0)
    ratio = setup.geometry.fin_base_to_fork
    fl, fr = _fish_in(left, cl, DEFAULT_PARAMS, ratio), _fish_in(right, cr, DEFAULT_PARAMS, ratio)
    out["left"], out["right"] = fl, fr
    t0 = _tick(timings, "detect", t0)
    F = fundamental_from_projections(np.asarray(calib.P1, float), np.asarray(calib.P2, float))
    up = up_direction(calib, setup)
    cands = [(i, j, _orient(fl[i], fr[j], swapped)) for i, j, swapped, _ in candidate_pairs(calib, F, fl, fr)]
    used_l, used_r, pairs = set(), set(), []
    for (i, j, (pts1, pts2, head)), solid in zip(cands, _solids(calib, setup, up, [c[2][:2] for c in cands]),
                                                 strict=True):
        if i in used_l or j in used_r or solid is None:
            continue
        used_l.add(i)
        used_r.add(j)
        pts1, pts2, gap = ends_from_both_views(F, pts1, pts2)
        pairs.append((fl[i], fr[j], pts1, pts2, head, gap))
        out["pairs"].append((i, j))
    if not pairs:
        _tick(timings, "stereo", t0)
        return out
    # snout and fork only: a window on the midline slides along a body lying along the epipolar line
    ends2, ncc = refine(cl.full, cr.full, calib, F, np.vstack([p[2][:2] for p in pairs]),
                        np.vstack([p[3][:2] for p in pairs]), _patch(fl))
    sets, solid_pts = [], []
    for k, (a, b, pts1, pts2, _, _) in enumerate(pairs):
        pts2 = np.vstack([ends2[2 * k:2 * k + 2], pts2[2:]])
        poly = np.vstack([pts2[0], pts2[2:], pts2[1]])
        if not (a.fork_seen and b.fork_seen):        # midline and fork: where the body crosses the line
            pts2[1:], crossed = body_crossings(F, pts1[1:], poly, pts2[1:])
            crossed = crossed[1:]
        else:                                        # the midline only
            pts2[2:], crossed = body_crossings(F, pts1[2:], poly, pts2[2:])
        solid_pts.append(np.r_[True, True, crossed])
        sets.append((pts1, pts2))
    for k, ((a, b, _, fused2, head, gap), (pts1, pts2), solid) in enumerate(zip(pairs, sets,
                                                                             _solids(calib, setup, up, sets),
                                                                             strict=True)):
        if solid is None:
            continue
        if not (a.fork_seen and b.fork_seen):
            # a fork placed from the fin base is no feature both views see: its window matched along
            # the line (and the crossing after it) follows the left fork's error. The line's depth
            # keeps that match; where along the line the fork lies, the right view's own place says too
            pts2 = pts2.copy()
            pts2[1] = fused2[1]
        solid = _on_axis(calib, up, solid, pts1, pts2, solid_pts[k])
        m = _measure(setup, a, b, pts1, pts2, head, solid, ncc[2 * k:2 * k + 2], gap)
        out["measured"].append(m)
        out["measured_pair"].append(k)
    if out["measured"]:
        # the score: the fitted chance the report is right (vision.surface_score), from its figures
        q = {k: np.array([m.quality[k] for m in out["measured"]]) for k in out["measured"][0].quality}
        for m, c in zip(out["measured"], surface_score.chance(q), strict=True):
            m.score = float(c)
    _tick(timings, "stereo", t0)
    return out
