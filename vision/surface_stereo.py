"""Stereo for the surface setup: which right fish is which left fish, and the right image's points
refined by correlation.

Pairing: a left and a right fish are one fish when the right snout and body centre lie on the
epipolar lines of the left ones, within a band of 2 px + 4 % of the fish's length (silhouette points
of two views are not exactly one physical point). A pairing that fits with snout and fork swapped is kept as a
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

# views' forks this far apart (per unit of length) or closer are averaged (see ends_from_both_views)
FORK_MEAN_GAP = 0.035


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
    """Candidate pairings (left i, right j, swapped, epipolar distance / band), best first. The same
    way round, the snouts and the body centres (middle midline points) must lie on each other's
    epipolar lines: not the forks, which each view places from its own view of the fin base. Swapped
    (the views disagree on the head), the snout of each on the line of the other's fork."""
    if not fl or not fr:
        return []
    def pts(fish, which, side):
        return _undist(calib, np.array([getattr(f, which) if which != "centre" else f.mid[len(f.mid) // 2]
                                         for f in fish]), side)
    sl, kl, cl = pts(fl, "snout", 1), pts(fl, "fork", 1), pts(fl, "centre", 1)
    sr, kr, cr = pts(fr, "snout", 2), pts(fr, "fork", 2), pts(fr, "centre", 2)
    band = 2.0 + 0.04 * np.array([f.length_px for f in fl])[:, None]
    same = np.maximum(line_dist(F, sl, sr), line_dist(F, cl, cr)) / band
    swap = np.maximum(line_dist(F, sl, kr), line_dist(F, kl, sr)) / band
    out = []
    for cost, swapped in ((same, False), (swap, True)):
        i, j = np.nonzero(cost < 1.0)
        out += [(int(a), int(b), swapped, float(cost[a, b])) for a, b in zip(i, j, strict=True)]
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


def on_right_body(F: np.ndarray, pts1: np.ndarray, poly2: np.ndarray, guess2: np.ndarray,
                  min_sin: float = 0.35) -> np.ndarray:
    """See ``body_crossings`` (the points only)."""
    return body_crossings(F, pts1, poly2, guess2, min_sin)[0]


def body_crossings(F: np.ndarray, pts1: np.ndarray, poly2: np.ndarray, guess2: np.ndarray,
                   min_sin: float = 0.35, past_end: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Right points (N, 2) for left points on a fish's body (midline points, the fork): where each
    left point's epipolar line crosses the right view's midline ``poly2`` (K, 2), the last segment
    extended past its end (the fork lies on the midline's continuation). A point seen only as a
    place along the body (not as a feature both views find) is fixed this way by the body's
    position across the line, which both views agree on. Where the line crosses the body at less
    than asin(``min_sin``) (~20 deg: a fish lying along the epipolar lines) the crossing is
    ill-conditioned and ``guess2`` is kept. ``past_end`` (px): how far the last segment runs on
    past the midline's end (by default its own length). Also returns which points (N,) were crossings."""
    pts1 = np.asarray(pts1, float).reshape(-1, 2)
    out = np.asarray(guess2, float).reshape(-1, 2).copy()
    a, b = poly2[:-1], poly2[1:]                                  # segments (S, 2)
    lines = np.c_[pts1, np.ones(len(pts1))] @ F.T                 # (N, 3)
    lines /= np.maximum(np.linalg.norm(lines[:, :2], axis=1, keepdims=True), 1e-12)
    da = lines[:, :2] @ a.T + lines[:, 2:]                        # signed distances (N, S)
    db = lines[:, :2] @ b.T + lines[:, 2:]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = da / (da - db)                                        # crossing parameter on each segment
    seg = b - a
    seg_len = np.maximum(np.linalg.norm(seg, axis=1), 1e-12)
    sin = np.abs(lines[:, :2] @ (seg / seg_len[:, None]).T)       # |cos(normal, seg)| = sin(line, seg)
    hi = np.ones(len(a))
    hi[-1] = 2.0 if past_end is None else 1.0 + past_end / seg_len[-1]     # it runs on to the fork
    ok = np.isfinite(t) & (t >= 0) & (t <= hi) & (sin >= min_sin)
    found = np.zeros(len(pts1), bool)
    if not ok.any():
        return out, found
    cost = np.where(ok, np.abs(t - 0.5), np.inf)
    j = cost.argmin(axis=1)
    rows = np.flatnonzero(np.isfinite(cost[np.arange(len(pts1)), j]))
    tj = t[rows, j[rows]]
    out[rows] = a[j[rows]] + tj[:, None] * seg[j[rows]]
    found[rows] = True
    return out, found


def ends_from_both_views(F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray,
                         max_fork_gap: float = FORK_MEAN_GAP) -> tuple[np.ndarray, np.ndarray, float]:
    """Snout and fork of one fish from both views' own ends: (pts1, pts2) [snout, fork, midline...]
    each (2 + K, 2), oriented alike; returns them with the ends replaced, and the views' fork gap
    (the right's own fork from where the left fork's epipolar line crosses the right midline, per
    unit of the right's length).

    Each end is carried into the other view where its epipolar line crosses that view's midline (run
    on past the end). The snout: the one further out. A view loses a snout to a pale or sheen-lit
    head, never draws one past the tip (rendered tanks, seeds 7000+: of 299 fish found in both
    views, 54 had snouts over 2 % of the length apart; the further one was within 3 % for 74 % of
    them, the left's for 45 %, their mean for 17 %). The fork: the two views' mean where they are within
    ``max_fork_gap`` of the length (2-3.5 % apart: within 3 % for 76 %, the left's 68 %); further
    apart neither view is to be trusted (the further one 53 %), and the left's is kept for the
    gap to rule on."""
    pts1, pts2 = np.array(pts1, float), np.array(pts2, float)
    poly1 = np.vstack([pts1[0], pts1[2:], pts1[1]])          # snout .. fork
    poly2 = np.vstack([pts2[0], pts2[2:], pts2[1]])
    length2 = max(float(np.linalg.norm(pts2[0] - pts2[1])), 1.0)
    reach = 0.3 * length2                                 # an end as far past the other view's
    s2_of_1 = body_crossings(F, pts1[:1], poly2[::-1], pts2[:1], past_end=reach)[0][0]
    k2_of_1 = body_crossings(F, pts1[1:2], poly2, pts2[1:2], past_end=reach)[0][0]
    s1_of_2 = body_crossings(F.T, pts2[:1], poly1[::-1], pts1[:1], past_end=reach)[0][0]
    k1_of_2 = body_crossings(F.T, pts2[1:2], poly1, pts1[1:2], past_end=reach)[0][0]
    gap = float(np.linalg.norm(pts2[1] - k2_of_1) / length2)
    head = pts1[0] - pts1[1]
    if (s1_of_2 - pts1[0]) @ head > 0:                   # the right view's snout is further out
        pts1[0] = s1_of_2
    else:
        pts2[0] = s2_of_1
    if gap <= max_fork_gap:
        pts1[1], pts2[1] = (pts1[1] + k1_of_2) / 2, (k2_of_1 + pts2[1]) / 2
    return pts1, pts2, gap


def _rays(calib, pts: np.ndarray, which: int) -> tuple[np.ndarray, np.ndarray]:
    """Optical centre (3,) and unit ray directions (N, 3) through pixels of one camera."""
    P = np.asarray(calib.P1 if which == 1 else calib.P2, float)
    M = P[:, :3]
    C = -np.linalg.solve(M, P[:, 3])
    uv = _undist(calib, np.asarray(pts, float).reshape(-1, 2), which)
    r = np.linalg.solve(M, np.c_[uv, np.ones(len(uv))].T).T
    return C, r / np.linalg.norm(r, axis=1, keepdims=True)


def fit_axis(X: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares 3-D line (point, unit direction) through points (N, 3)."""
    w = np.ones(len(X)) if w is None else np.asarray(w, float)
    c = (w[:, None] * X).sum(axis=0) / w.sum()
    D = (X - c) * np.sqrt(w)[:, None]
    _, _, vt = np.linalg.svd(D, full_matrices=False)
    return c, vt[0]


def fit_axis_robust(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``fit_axis`` twice, the second time with the points far off the first line (over 2.5 robust
    sd, and over 2 % of the length: a midline point matched on the wrong part of the body) left out."""
    c, d = fit_axis(X)
    r = np.linalg.norm((X - c) - np.outer((X - c) @ d, d), axis=1)
    length = np.ptp(X @ d)                  # never an outlier within 2 % of the fish's length
    keep = r <= max(2.5 * 1.4826 * np.median(r), 0.02 * length)
    return fit_axis(X[keep]) if keep.sum() >= 3 else (c, d)


def ends_on_axis(calib, c: np.ndarray, d: np.ndarray, px1: np.ndarray, px2: np.ndarray) -> np.ndarray:
    """Points (N, 3) on the line c + s d for end pixels seen in both views (px1, px2: (N, 2)): per
    view the line's point nearest the pixel's ray, the two views averaged. The image places an end
    along the fish to a fraction of a pixel; the depth comes from the whole fish's line."""
    s = np.zeros(len(px1))
    for which, px in ((1, px1), (2, px2)):
        C, r = _rays(calib, px, which)
        b = r @ d
        w0 = c - C
        den = np.maximum(1 - b ** 2, 1e-9)
        s += (b * (r @ w0) - w0 @ d) / den
    return c + (s / 2)[:, None] * d
