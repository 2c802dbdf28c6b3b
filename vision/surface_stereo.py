"""Stereo for the surface setup: which right fish is which left fish, and the right image's points
refined by correlation.

Pairing: a left and a right fish are one fish when the right snout and fork lie on the epipolar lines
of the left ones, within a band of 2 px + 4 % of the fish's length (silhouette points of two views
are not exactly one physical point). A pairing that fits with snout and fork swapped is kept as a
candidate too: the two views then disagree on the head, which the caller settles.

Refinement: a silhouette's extreme point is found to about half a pixel in each view independently,
and along the epipolar line that half pixel is depth (at 1 m and a 200 mm baseline, ~5 mm a pixel).
Each left point's window is therefore matched along its epipolar line, a few pixels either side of
the right view's own detection (vision.matching.match_points, zero-mean NCC, sub-pixel), and the
match replaces the detection when it correlates well. Needs undistorted images: with a calibration
that has distortion the detections are used as they are.
"""
from __future__ import annotations

import numpy as np

from vision.matching import match_points
from vision.surface_shape import Fish2D
from vision.triangulation import undistort_pixels


def line_dist(F: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Distance (N, M) of right points p2 (M, 2) to the epipolar lines of left points p1 (N, 2)."""
    lines = np.c_[p1, np.ones(len(p1))] @ F.T
    lines /= np.maximum(np.linalg.norm(lines[:, :2], axis=1, keepdims=True), 1e-12)
    return np.abs(lines[:, :2] @ p2.T + lines[:, 2:])


def _undist(calib, pts, which):
    if not calib.has_distortion or len(pts) == 0:
        return pts
    K, D = (calib.K1, calib.D1) if which == 1 else (calib.K2, calib.D2)
    return undistort_pixels(pts, K, D)


def candidate_pairs(calib, F, fl: list[Fish2D], fr: list[Fish2D]) -> list[tuple[int, int, bool, float]]:
    """Candidate pairings (left i, right j, swapped, epipolar distance / band), best first."""
    if not fl or not fr:
        return []
    sl = _undist(calib, np.array([f.snout for f in fl]), 1)
    kl = _undist(calib, np.array([f.fork for f in fl]), 1)
    sr = _undist(calib, np.array([f.snout for f in fr]), 2)
    kr = _undist(calib, np.array([f.fork for f in fr]), 2)
    band = 2.0 + 0.04 * np.array([f.length_px for f in fl])[:, None]
    same = np.maximum(line_dist(F, sl, sr), line_dist(F, kl, kr)) / band
    swap = np.maximum(line_dist(F, sl, kr), line_dist(F, kl, sr)) / band
    out = []
    for cost, swapped in ((same, False), (swap, True)):
        i, j = np.nonzero(cost < 1.0)
        out += [(int(a), int(b), swapped, float(cost[a, b])) for a, b in zip(i, j, strict=False)]
    return sorted(out, key=lambda x: x[3])


def refine(left, right, calib, F, pts1: np.ndarray, pts2: np.ndarray, patch: int,
           reach_px: float = 4.0, min_ncc: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """Right points (N, 2) re-found by correlation with the left windows along the epipolar lines,
    +-``reach_px`` around ``pts2``; and the NCC of each (NaN where the detection was kept)."""
    pts1 = np.asarray(pts1, float).reshape(-1, 2)
    pts2 = np.asarray(pts2, float).reshape(-1, 2)
    ncc = np.full(len(pts1), np.nan)
    if calib.has_distortion or len(pts1) == 0:
        return pts2, ncc
    lines = np.c_[pts1, np.ones(len(pts1))] @ F.T
    d = np.c_[lines[:, 1], -lines[:, 0]]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    seg = np.stack([pts2 - reach_px * d, pts2 + reach_px * d], axis=1)
    res = match_points(left, right, pts1, F, segments=seg, patch=patch, band_px=1.0, min_ncc=min_ncc,
                       ambiguity_margin=0.0)
    ok = res.valid & np.isfinite(res.pts2[:, 0])
    out = pts2.copy()
    out[ok] = res.pts2[ok]
    ncc[ok] = res.ncc[ok]
    return out, ncc
