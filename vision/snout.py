"""The snout: the other end of the fish, found from the fork's position and axis (edge profile).

From the fork the body runs forward along the fin's axis and ends at the snout tip. A band a few
samples wide along the axis is sampled (pyramid level matched to the sampling step) and turned
into a signed profile with the fork's own grey levels: > 0 where it looks like the fish just ahead
of the fork, < 0 where it looks like the water in the notch. The snout is where the profile leaves
the fish for good: a candidate position scores the fraction of fish samples between the fork and it
times the fraction of water samples over a stretch after it. Local maxima of that score are
candidates, located at the profile's mid-level crossing (sub-sample, linear), best first; the 3-D
association picks among them with the other camera and the species geometry.

Compared (tests/vision/test_snout.py, rendered pairs in bench/bench_survey_underwater.py): the
strongest fish-to-water edge of the profile (the derivative's extreme) is thrown by glints, stripes
and shade edges inside the body; the first crossing after the fork stops at any dark band across the
body. The fraction score needs the body to be fish-like for most of its length, not everywhere.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vision.fins import sample_frames

SAMPLES = 240           # profile samples over the search range
ACROSS = 5              # rows across the axis, averaged


@dataclass
class Snouts:
    """K candidates per fork (N, K), best first; distance NaN where there is none."""

    dist_px: np.ndarray     # (N, K) along the axis from the fork
    xy: np.ndarray          # (N, K, 2)
    strength: np.ndarray    # (N, K) 0..1


def find_snouts(pyr: list[np.ndarray], xy: np.ndarray, angle: np.ndarray, half_band_px: np.ndarray,
                fish_level: np.ndarray, water_level: np.ndarray, lo_px: np.ndarray, hi_px: np.ndarray,
                k: int = 3, min_strength: float = 0.35) -> Snouts:
    """Snout candidates along each fork's axis between ``lo_px`` and ``hi_px`` from it."""
    N = len(xy)
    dist = np.full((N, k), np.nan)
    if N == 0:
        return Snouts(dist, np.full((0, k, 2), np.nan), np.zeros((0, k)))
    axes = np.c_[np.cos(angle), np.sin(angle)]
    lo = np.maximum(np.asarray(lo_px, float), 1.0)
    hi = np.maximum(np.asarray(hi_px, float), lo + 2.0)
    u = np.linspace(0.0, 1.0, SAMPLES + 1)
    xs = u[None] * hi[:, None]                                       # from the fork to hi
    step = hi / SAMPLES
    ys = np.linspace(-1.0, 1.0, ACROSS)[None] * np.asarray(half_band_px, float)[:, None]
    prof = np.full((N, SAMPLES + 1), np.nan, np.float32)
    lev = np.clip(np.floor(np.log2(np.maximum(step, 1.0))).astype(int), 0, len(pyr) - 1)
    for lv in np.unique(lev):
        idx = np.flatnonzero(lev == lv)
        f = 2.0 ** -lv
        band = sample_frames(pyr[lv], (xy[idx] + 0.5) * f - 0.5, axes[idx], xs[idx] * f, ys[idx] * f)
        prof[idx] = np.median(band, axis=1)
    mid = 0.5 * (fish_level + water_level)
    scale = np.maximum(np.abs(fish_level - water_level), 1e-6) * np.sign(fish_level - water_level)
    s = (prof - mid[:, None]) / scale[:, None]                      # fish ~ +0.5, water ~ -0.5
    inside = np.isfinite(s)
    fishy = np.where(inside, s > 0, False).astype(float)
    watery = np.where(inside, s < 0, False).astype(float)           # off the image: maybe more fish
    c_f = np.c_[np.zeros(N), np.cumsum(fishy, axis=1)]
    c_w = np.c_[np.zeros(N), np.cumsum(watery, axis=1)]
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
        block = np.abs(i[None] - best[:, None]) <= m[:, None]
        work[block] = -1.0
    pts = xy[:, None] + dist[..., None] * axes[:, None]
    return Snouts(dist, pts, strength)


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
