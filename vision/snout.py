"""The snout: the other end of the fish, found from the fork's position and the body's axis
(an edge profile, then the tip's outline).

From the fork the body runs forward and ends at the snout tip. Bands a few samples wide are
sampled along a fan of directions around the body's axis (pyramid level matched to the step) and
turned into profiles of how unlike the water in the notch each sample is, in units of the fin's
own contrast (> 0 fish, < 0 water). On each, a position scores the fraction of fish samples from
the fork to it times the fraction of water samples over a stretch after it; local maxima are
candidates (sub-sample, at the mid-level crossing). The direction reaching farthest is kept (the
snout is the body's farthest point from the fork; a peak at the fan's edge is a side of the body
and is dropped), and each candidate's tip is then found across it: the front-most point of the
outline, a parabola through the rows near the axis, against the water just ahead of it.

Alternatives measured (correct fork pairs of rendered fully visible fish, 60 scenes,
bench/bench_survey_underwater.py's renderer; "found" = the true snout among the candidates within
2 % of the length, left/right image): one profile along the fin's own axis 4/16 and 8/16 (on 30
scenes: the fin's axis is ~10 degrees off too often); a +-20 degree fan around it 15/28, 16/28;
the fan around the body region's axis 17/28, 16/28; that fan at +-12 degrees, 2 degree steps
(kept) 20/28, 15/28. On drawn fish (tests/vision/test_snout.py) the first fish-to-water crossing
after the fork stops at a water-coloured bar across the body, where the fraction score does not;
the strongest edge of the profile is thrown by glints and shade edges inside the body.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vision.fins import sample_frames
from vision.fork import nan_median

SAMPLES = 240           # profile samples over the search range
ACROSS = 5              # rows across the axis, averaged


@dataclass
class Snouts:
    """K candidates per fork (N, K), best first; distance NaN where there is none."""

    dist_px: np.ndarray     # (N, K) along the axis from the fork
    xy: np.ndarray          # (N, K, 2)
    strength: np.ndarray    # (N, K) 0..1


FAN_DEG = np.arange(-12.0, 12.1, 2.0)


def find_snouts(pyr: list[np.ndarray], xy: np.ndarray, angle: np.ndarray, half_band_px: np.ndarray,
                fish_level: np.ndarray, water_level: np.ndarray, lo_px: np.ndarray, hi_px: np.ndarray,
                k: int = 3, min_strength: float = 0.35, fan_deg: np.ndarray = FAN_DEG) -> Snouts:
    """Snout candidates ahead of each fork between ``lo_px`` and ``hi_px`` from it.

    A fin's axis is good to ~10 degrees (a flexible fin, a bent body): profiles are taken over a
    fan of directions around it (``fan_deg``) and the one reaching farthest through fish to water
    is kept (the snout is the body's farthest point from the fork); ``refine_tips`` then finds
    the tip across it."""
    N = len(xy)
    A = len(fan_deg)
    if N == 0:
        return Snouts(np.full((0, k), np.nan), np.full((0, k, 2), np.nan), np.zeros((0, k)))
    rep = np.repeat(np.arange(N), A)
    fan = np.repeat(np.asarray(angle, float), A) + np.tile(np.radians(fan_deg), N)
    fish_level = np.asarray(fish_level, float).reshape(N, -1)
    water_level = np.asarray(water_level, float).reshape(N, -1)
    dist, strength, contrast = _along(pyr, xy[rep], fan, np.asarray(half_band_px, float)[rep], fish_level[rep],
                                      water_level[rep], np.asarray(lo_px, float)[rep], np.asarray(hi_px, float)[rep],
                                      k, min_strength)
    d0 = np.where(np.isfinite(dist[:, 0]), dist[:, 0], -np.inf).reshape(N, A)
    s0 = strength[:, 0].reshape(N, A)
    best = np.where(s0 >= 0.9 * s0.max(axis=1, keepdims=True), d0, -np.inf).argmax(axis=1)
    pick = np.arange(N) * A + best
    dist, strength, contrast, angle = dist[pick], strength[pick], contrast[pick], fan[pick]
    # the reach peaking at the fan's edge is a side of the body (or a fish leaving the frame)
    edge = (best == 0) | (best == A - 1)
    dist[edge] = np.nan
    strength[edge] = 0.0
    axes = np.column_stack((np.cos(angle), np.sin(angle)))
    pts = xy[:, None] + dist[..., None] * axes[:, None]
    # the tip itself, off the axis by up to half the fan's step
    flat = pts.reshape(-1, 2)
    has = np.isfinite(flat[:, 0])
    if has.any():
        L = np.broadcast_to(np.nan_to_num(dist), (N, k)).reshape(-1)[has]
        r = np.repeat(np.arange(N), k)[has]
        tips, found = refine_tips(pyr, flat[has], angle[r], L, water_level[r], contrast[r])
        flat = flat.copy()
        flat[has] = tips                          # where no cap is seen, the profile's own end stays
        pts = flat.reshape(N, k, 2)
        weak = np.zeros(N * k, bool)
        weak[np.flatnonzero(has)[~found]] = True
        strength = np.where(weak.reshape(N, k), 0.5 * strength, strength)
        dist = np.where(np.isfinite(dist), np.linalg.norm(pts - xy[:, None], axis=2), np.nan)
    return Snouts(dist, pts, strength)


def _along(pyr, xy, angle, half_band_px, fish_level, water_level, lo_px, hi_px, k, min_strength):
    """Candidate distances (N, k) and strengths (N, k) on each row's own straight profile, and the
    fin's contrast (N,)."""
    N = len(xy)
    dist = np.full((N, k), np.nan)
    axes = np.column_stack((np.cos(angle), np.sin(angle)))
    lo = np.maximum(np.asarray(lo_px, float), 1.0)
    hi = np.maximum(np.asarray(hi_px, float), lo + 2.0)
    u = np.linspace(0.0, 1.0, SAMPLES + 1)
    xs = u[None] * hi[:, None]                                       # from the fork to hi
    step = hi / SAMPLES
    ys = np.linspace(-1.0, 1.0, ACROSS)[None] * np.asarray(half_band_px, float)[:, None]
    fish_level = np.asarray(fish_level, float).reshape(N, -1)
    water_level = np.asarray(water_level, float).reshape(N, -1)
    C = fish_level.shape[1]
    prof = np.full((N, SAMPLES + 1, C), np.nan, np.float32)
    lev = np.clip(np.floor(np.log2(np.maximum(step, 1.0))).astype(int), 0, len(pyr) - 1)
    for lv in np.unique(lev):
        idx = np.flatnonzero(lev == lv)
        f = 2.0 ** -lv
        band = sample_frames(pyr[lv], (xy[idx] + 0.5) * f - 0.5, axes[idx], xs[idx] * f, ys[idx] * f)
        # np.median's value across the rows (NaN where any is NaN)
        prof[idx] = median_across(band.reshape(len(idx), ACROSS, SAMPLES + 1, C))
    # unlike the water by more than half the fin's own contrast: fish (> 0)
    contrast = np.maximum(np.linalg.norm(fish_level - water_level, axis=1), 1e-6)
    s = np.linalg.norm(prof - water_level[:, None], axis=2) / contrast[:, None] - 0.5
    inside = np.isfinite(s)
    fishy = np.where(inside, s > 0, False).astype(float)
    watery = np.where(inside, s < 0, False).astype(float)           # off the image: maybe more fish
    c_f = np.column_stack((np.zeros(N), np.cumsum(fishy, axis=1)))
    c_w = np.column_stack((np.zeros(N), np.cumsum(watery, axis=1)))
    i = np.arange(SAMPLES + 1)
    start = np.round(0.1 * lo / step).astype(int)                    # skip the fin itself
    m = np.maximum(np.round(0.1 * (lo + hi) / 2 / step).astype(int), 3)
    n_before = np.maximum(i[None] - start[:, None], 1)
    before = (c_f[:, 1:] - np.take_along_axis(c_f, np.clip(start, 0, SAMPLES)[:, None], axis=1)) / n_before
    end = np.minimum(i[None] + m[:, None], SAMPLES + 1)
    after = (np.take_along_axis(c_w, end, axis=1) - c_w[:, 1:]) / np.maximum(end - i[None] - 1, 1)
    score = before * after * (i[None] * step[:, None] >= lo[:, None]) * inside
    # local maxima over +-m samples, best first (a loop over k picks, vectorised over forks)
    work = score.copy()
    strength = np.zeros((N, k))
    rows = np.arange(N)
    for j in range(k):
        best = work.argmax(axis=1)
        val = work[rows, best]
        good = val >= min_strength
        # the crossing: last fish sample at or before best, to the first water sample after it
        pos = _crossing(s, best)
        dist[:, j] = np.where(good, pos * step, np.nan)
        strength[:, j] = np.where(good, val, 0.0)
        block = np.abs(i[None] - best[:, None]) <= 2 * m[:, None]
        work[block] = -1.0
    return dist, strength, contrast


def median_across(band: np.ndarray) -> np.ndarray:
    """Median over axis 1 (NaN where any is NaN), for 5 rows by min/max comparisons (exact: the
    median of 5 is the median of e and the larger of the pairs' minima and the smaller of their
    maxima; ~6x cheaper than sorting the axis), else by one sort."""
    if band.shape[1] != 5:
        srt = np.sort(band, axis=1)                                                   # NaN sort last
        return np.where(np.isnan(srt[:, -1]), np.nan, srt[:, band.shape[1] // 2])
    a, b, c, d, e = (band[:, i] for i in range(5))
    lo = np.maximum(np.minimum(a, b), np.minimum(c, d))
    hi = np.minimum(np.maximum(a, b), np.maximum(c, d))
    med = np.maximum(np.minimum(lo, hi), np.minimum(np.maximum(lo, hi), e))
    return np.where(np.isnan(band).any(axis=1), np.nan, med)


def _crossing(s: np.ndarray, best: np.ndarray) -> np.ndarray:
    """Sub-sample index where s falls through 0 nearest ``best`` (within +-3 samples), else best."""
    N, n = s.shape
    off = np.arange(-3, 4)
    j = np.clip(best[:, None] + off[None], 0, n - 2)
    a = np.take_along_axis(s, j, axis=1)
    b = np.take_along_axis(s, j + 1, axis=1)
    falls = (a > 0) & (b <= 0)
    near = np.where(falls, np.abs(off)[None], 99).argmin(axis=1)
    has = falls[np.arange(N), near]
    ja, aa, bb = j[np.arange(N), near], a[np.arange(N), near], b[np.arange(N), near]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = aa / (aa - bb)
    return np.where(has, ja + frac, best.astype(float))


def refine_tips(pyr: list[np.ndarray], tips: np.ndarray, angle: np.ndarray, length_px: np.ndarray,
                water: np.ndarray, contrast: np.ndarray, samples: int = 33) -> tuple[np.ndarray, np.ndarray]:
    """The snout tip near each candidate (M, 2): the front-most point of the body outline, found
    across the axis as well as along it (a fin's axis is a few degrees off, which would put a
    point on the axis ~5 % of the length to the side of the tip). Each row across the axis is
    scanned from the water ahead back to its first fish sample; a parabola through the rows near
    the front-most crossing gives the tip (sub-sample). Returns the tips and whether each was
    found (else the candidate is returned unchanged)."""
    M = len(tips)
    if M == 0:
        return tips, np.zeros(0, bool)
    u = np.linspace(-1.0, 1.0, samples)
    along = u[None] * (0.06 * length_px)[:, None]
    across = u[None] * (0.1 * length_px)[:, None]
    step = 0.12 * length_px / (samples - 1)
    axes = np.column_stack((np.cos(angle), np.sin(angle)))
    C = pyr[0].shape[2] if pyr[0].ndim == 3 else 1
    win = np.full((M, samples, samples, C), np.nan, np.float32)
    lev = np.clip(np.floor(np.log2(np.maximum(step, 1.0))).astype(int), 0, len(pyr) - 1)
    for lv in np.unique(lev):
        idx = np.flatnonzero(lev == lv)
        f = 2.0 ** -lv
        win[idx] = sample_frames(pyr[lv], (tips[idx] + 0.5) * f - 0.5, axes[idx], along[idx] * f,
                                 across[idx] * f).reshape(len(idx), samples, samples, C)
    # local levels: the water ahead of the tip, the head behind it (the notch's water can be
    # another colour: light changes with depth along a tilted fish)
    front = u > 0.6
    back = u < -0.5
    mid = np.abs(u) <= 0.3
    ahead = np.stack([nan_median(win[:, :, front, c]) for c in range(C)], axis=1)        # (M, C)
    head = np.stack([nan_median(win[:, mid][:, :, back, c]) for c in range(C)], axis=1)
    water = np.where(np.isfinite(ahead), ahead, np.asarray(water, float).reshape(M, -1))
    contrast = np.linalg.norm(head - water, axis=1)
    contrast = np.where(np.isfinite(contrast), contrast, 0.0)
    s = np.linalg.norm(win - water[:, None, None], axis=3) / np.maximum(contrast, 1e-6)[:, None, None] - 0.5
    rev = s[:, :, ::-1]                                       # from the front backwards
    fishy = rev >= 0
    first = fishy.argmax(axis=2)
    has = fishy.any(axis=2) & (first > 0) & ~np.isnan(rev).any(axis=2)
    j = np.clip(first, 1, samples - 1)
    a = np.take_along_axis(rev, (j - 1)[..., None], axis=2)[..., 0]
    b = np.take_along_axis(rev, j[..., None], axis=2)[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        pos = (samples - 1 - (j - 1)) - (-a) / (b - a)        # index along u, front crossing
    x = np.where(has, -1.0 + 2.0 * pos / (samples - 1), -np.inf)   # in units of the along half-range
    best = np.where(np.abs(u)[None] <= 0.5, x, -np.inf).argmax(axis=1)     # near the axis: the fan is 4 deg fine
    yb = u[best]
    w = has & (np.abs(u[None] - yb[:, None]) <= 0.35)
    xs = np.where(w, x, 0.0)
    # weighted least squares x = c0 + c1 y + c2 y^2 per candidate
    Y = np.stack([np.ones_like(u), u, u * u], axis=1)                  # (rows, 3)
    A = np.einsum("mr,ri,rj->mij", w.astype(float), Y, Y)
    bvec = np.einsum("mr,ri,mr->mi", w.astype(float), Y, xs)
    ok = (w.sum(axis=1) >= 5) & (np.abs(np.linalg.det(A)) > 1e-9)
    coef = np.zeros((M, 3))
    if ok.any():
        coef[ok] = np.linalg.solve(A[ok], bvec[ok][..., None])[..., 0]
    c0, c1, c2 = coef.T
    with np.errstate(invalid="ignore", divide="ignore"):
        yv = np.where(c2 < 0, -c1 / (2 * c2), yb)
    yv = np.clip(yv, yb - 0.35, yb + 0.35)
    xv = c0 + c1 * yv + c2 * yv * yv
    # a tip is a cap: curving back on both sides, its front row inside the window (a slanted side
    # of the body has its front-most row at the window's edge)
    ok &= np.isfinite(xv) & (np.abs(xv) <= 1.0) & (contrast >= 3.0) & (c2 < 0) & (np.abs(yb) < 0.85)
    normal = np.column_stack((-axes[:, 1], axes[:, 0]))
    out = tips + (xv * 0.06 * length_px)[:, None] * axes + (yv * 0.1 * length_px)[:, None] * normal
    return np.where(ok[:, None], out, tips), ok
