"""Fish measured from above in a nursery tank (the paper's non-underwater setup, section 4.2, Fig. 6).

Per image (vision.surface_prep, .surface_regions, .surface_shape): noise reduction and a flat field
(the lamps' illumination divided out), region growing from seeds, each region's body axis, snout
tip, caudal-fork notch and midline points; which end is the head is decided by shape.

Across the pair: a left fish and a right fish are the same fish when the right snout and fork lie on
the epipolar lines of the left ones (within a band that grows with the fish's size). Each candidate
pairing is triangulated and checked in 3-D: fork length within the species' range
(``SurveySetup.geometry``), body axis within ``max_tilt_deg`` of the water surface. Pairs are taken
greedily, best first, one fish per region. When the two views disagree on which end is the head
(the pairing fits with snout and fork swapped), the view more sure of itself decides.

"Up" (the water surface's normal): ``SurveySetup.up_world`` when given; else, for this setup, the
direction from the tank towards the cameras, i.e. minus the mean of the two optical axes: cameras
over a tank look down, so the image-up of the underwater default would lie in the water surface.

Score (0..1), the product of the terms kept in ``quality``: epipolar residual of snout and fork
(``q_epipolar``), axis tilt against the surface (``q_tilt``), straightness of the body through the
intermediate points (``q_straight``; a fish bent sideways has a fork length shorter than its body),
head/tail confidence (``q_head``), the caudal fork found as a notch in both views (``q_fork``), the
outline free of lamp reflections (``q_glare``), and left/right agreement of the apparent length
(``q_views``). Fork length is the straight 3-D snout-fork distance (the contract); the length along
the body through the intermediate points is kept as ``body_mm``.
"""
from __future__ import annotations

import time

import numpy as np

from vision.calib_file import StereoCalibration
from vision.epipolar import fundamental_from_projections
from vision.surface_prep import contrast_map
from vision.surface_regions import RegionParams, find_regions
from vision.surface_shape import Fish2D, analyse
from vision.survey_types import FishMeasurement, SurveySetup
from vision.triangulation import triangulate_calibrated, undistort_pixels

MIN_SCORE = 0.05        # below this a "fish" is noise: not reported


def _tick(timings, stage, t0):
    if timings is not None:
        timings[stage] = timings.get(stage, 0.0) + time.perf_counter() - t0
    return time.perf_counter()


def detect_fish(img: np.ndarray, params: RegionParams = RegionParams()) -> list[Fish2D]:
    """Fish found in one image seen from above: front, rear and intermediate points of each."""
    c = contrast_map(img)
    out = []
    for r in find_regions(c, params):
        f = analyse(r)
        if f is not None and f.elongation >= params.min_elongation:
            out.append(f)
    return out


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


def _line_dist(F: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Distance (N, M) of right points p2 (M, 2) to the epipolar lines of left points p1 (N, 2)."""
    lines = np.c_[p1, np.ones(len(p1))] @ F.T
    lines /= np.maximum(np.linalg.norm(lines[:, :2], axis=1, keepdims=True), 1e-12)
    return np.abs(lines[:, :2] @ p2.T + lines[:, 2:])


def _undist(calib, pts, which):
    if not calib.has_distortion:
        return pts
    K, D = (calib.K1, calib.D1) if which == 1 else (calib.K2, calib.D2)
    return undistort_pixels(pts, K, D)


def _pairs(calib, F, fl: list[Fish2D], fr: list[Fish2D]):
    """Candidate pairings (i, j, swapped, epipolar distance / band), best first."""
    if not fl or not fr:
        return []
    sl = _undist(calib, np.array([f.snout for f in fl]), 1)
    kl = _undist(calib, np.array([f.fork for f in fl]), 1)
    sr = _undist(calib, np.array([f.snout for f in fr]), 2)
    kr = _undist(calib, np.array([f.fork for f in fr]), 2)
    size = np.array([f.length_px for f in fl])[:, None]
    band = 2.0 + 0.04 * size
    same = np.maximum(_line_dist(F, sl, sr), _line_dist(F, kl, kr)) / band
    swap = np.maximum(_line_dist(F, sl, kr), _line_dist(F, kl, sr)) / band
    out = []
    for cost, swapped in ((same, False), (swap, True)):
        i, j = np.nonzero(cost < 1.0)
        out += [(int(a), int(b), swapped, float(cost[a, b])) for a, b in zip(i, j)]
    return sorted(out, key=lambda x: x[3])


def _orient(a: Fish2D, b: Fish2D, swapped: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """Snout and fork pixels (2, 2) of a left/right pair after settling which end is the head, and
    the confidence of that decision."""
    if not swapped:
        conf = 1 - (1 - a.head_conf) * (1 - b.head_conf)
        return np.array([a.snout, b.snout]), np.array([a.fork, b.fork]), conf
    if a.head_conf >= b.head_conf:            # right view flipped
        return np.array([a.snout, b.fork]), np.array([a.fork, b.snout]), a.head_conf - b.head_conf
    return np.array([a.fork, b.snout]), np.array([a.snout, b.fork]), b.head_conf - a.head_conf


def _measure(calib, setup: SurveySetup, up, a: Fish2D, b: Fish2D, swapped: bool) -> FishMeasurement | None:
    snout_px, fork_px, head = _orient(a, b, swapped)
    mid_r = b.mid if not swapped else b.mid[::-1]
    if swapped and a.head_conf < b.head_conf:
        mid_l, mid_r = a.mid[::-1], b.mid
    else:
        mid_l = a.mid
    pts1 = np.vstack([snout_px[0], fork_px[0], mid_l])
    pts2 = np.vstack([snout_px[1], fork_px[1], mid_r])
    X, res = triangulate_calibrated(calib, pts1, pts2)
    if not np.all(np.isfinite(X)):
        return None
    S, K, M = X[0], X[1], X[2:]
    axis = S - K
    length_mm = float(np.linalg.norm(axis))
    g = setup.geometry
    if not (10 * g.min_length_cm <= length_mm <= 10 * g.max_length_cm):
        return None
    tilt = float(np.degrees(np.arcsin(min(abs(axis @ up) / length_mm, 1.0))))
    if tilt > g.max_tilt_deg:
        return None
    chain = np.vstack([S, M, K])
    body_mm = float(np.linalg.norm(np.diff(chain, axis=0), axis=1).sum())
    straight = length_mm / max(body_mm, 1e-9)
    epi = float(np.sqrt(np.mean(res[:2] ** 2)))
    views = min(a.length_px, b.length_px) / max(a.length_px, b.length_px)
    q = {
        "q_epipolar": float(np.exp(-(epi / (0.75 + 0.005 * a.length_px)) ** 2)),
        "q_tilt": float(np.clip(1 - (tilt / g.max_tilt_deg) ** 2, 0, 1)),
        "q_straight": float(np.clip((straight - 0.9) / 0.1, 0, 1)) ** 0.5,
        "q_head": float(0.5 + 0.5 * np.clip(head, 0, 1)),
        "q_fork": 1.0 if (a.fork_depth > 0 and b.fork_depth > 0) else (0.8 if a.fork_depth + b.fork_depth > 0 else 0.6),
        "q_glare": float(np.clip(1 - 2 * max(a.glare, b.glare), 0, 1)),
        "q_views": float(np.clip((views - 0.7) / 0.3, 0, 1)),
    }
    score = float(np.prod(list(q.values())))
    q.update({"epipolar_px": epi, "mid_epipolar_px": float(np.sqrt(np.mean(res[2:] ** 2))), "tilt_deg": tilt,
              "body_mm": body_mm, "straightness": straight, "head_conf": float(head),
              "fork_depth": float(min(a.fork_depth, b.fork_depth)), "range_mm": float(np.linalg.norm(
                  (S + K) / 2 - _centre(calib))), "length_px": a.length_px, "head_swapped": float(swapped)})
    return FishMeasurement(S, K, snout_px, fork_px, score, q)


def _centre(calib) -> np.ndarray:
    P = np.asarray(calib.P1, float)
    return -np.linalg.solve(P[:, :3], P[:, 3])


def measure_surface(left: np.ndarray, right: np.ndarray, calib: StereoCalibration, setup: SurveySetup,
                    timings: dict[str, float] | None = None) -> list[FishMeasurement]:
    """Fish measured in one pair seen from above (see module docstring). Never raises on a frame
    without fish: returns []."""
    t0 = time.perf_counter()
    cl, cr = contrast_map(left), contrast_map(right)
    t0 = _tick(timings, "prep", t0)
    params = RegionParams()
    fl = [f for f in (analyse(r) for r in find_regions(cl, params)) if f and f.elongation >= params.min_elongation]
    fr = [f for f in (analyse(r) for r in find_regions(cr, params)) if f and f.elongation >= params.min_elongation]
    t0 = _tick(timings, "detect", t0)
    F = fundamental_from_projections(np.asarray(calib.P1, float), np.asarray(calib.P2, float))
    up = up_direction(calib, setup)
    used_l, used_r, out = set(), set(), []
    for i, j, swapped, _ in _pairs(calib, F, fl, fr):
        if i in used_l or j in used_r:
            continue
        m = _measure(calib, setup, up, fl[i], fr[j], swapped)
        if m is None or m.score < MIN_SCORE:
            continue
        used_l.add(i)
        used_r.add(j)
        out.append(m)
    _tick(timings, "stereo", t0)
    return out
