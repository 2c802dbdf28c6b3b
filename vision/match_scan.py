"""The combined similarity and the dense scan along epipolar bands (used by vision.matching).

A dense scan samples one strip per point along its line in image 2 (``match_geometry``): candidate
windows are the strip's sliding windows. Zero-mean NCC numerators of all of them are one batched
matrix product per chunk of points (each template row against each strip row, BLAS) followed by a
sum along diagonals: candidate m of band row b gets sum_ij T[i, j] S[b + i, m + j]. Window means
and contrasts come from row sums of the strip and of its square, boxed along the line. The scan is
exhaustive along the line and coarse to fine across it (every other band row, then every row near
the best); the best candidate is refined by parabolas along and across the line.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from vision.match_geometry import frame_grid, sample

if TYPE_CHECKING:
    from vision.matching import Weights

_CHUNK_FLOATS = 2_000_000      # per chunk of points (strips, maps, products): bounds memory, keeps cache
_FINE = 5                      # fine pass: rows and columns of candidates around the coarse best


@dataclass(frozen=True)
class Options:
    """match_points' settings in the scan's terms (band: whole-pixel offsets either side of the line)."""

    patch: int
    band: int
    weights: Weights
    line_sigma: float
    min_ncc: float
    margin: float
    exclusion: int


@dataclass
class Found:
    """Best candidate per point (arrays over the points being matched)."""

    pts2: np.ndarray
    score: np.ndarray
    ncc: np.ndarray
    second: np.ndarray
    line: np.ndarray
    scale: np.ndarray
    index: np.ndarray | None = None


def stats(win: np.ndarray):
    """Mean, standard deviation and zero-mean copy of windows (..., p, p)."""
    mean = win.mean(axis=(-2, -1))
    zero = win - mean[..., None, None]
    std = np.sqrt((zero * zero).mean(axis=(-2, -1)))
    return mean, std, zero


def ratio(a, b):
    """min/max of two non-negative quantities, in [0, 1]."""
    return np.minimum(a, b) / np.maximum(np.maximum(a, b), np.float32(1e-6))


def _combine(w: Weights, ncc, line, mean, contrast, size=None, orientation=None):
    terms = [(w.ncc, ncc), (w.line, line), (w.mean, mean), (w.contrast, contrast)]
    if size is not None:
        terms += [(w.size, size), (w.orientation, orientation)]
    total = sum(weight for weight, _ in terms)
    return sum(np.float32(weight / total) * term for weight, term in terms)


def line_term(o: Options, offsets):
    return np.exp(-0.5 * (np.asarray(offsets, np.float32) / np.float32(o.line_sigma)) ** 2)


def best_scale(o: Options, tmpl_stats, num, w_mean, w_std, line, extra=()):
    """Scores of candidates against templates at S scales, the best scale kept.

    tmpl_stats (mean, std): (N, S); num, the NCC numerators: (N, S, *C); window mean/std: (N, *C);
    line and extra terms broadcast to (N, 1, *C). Returns score, ncc, scale index, each (N, *C)."""
    pad = (slice(None), slice(None)) + (None,) * (num.ndim - 2)
    t_mean, t_std = (t[pad] for t in tmpl_stats)
    w_mean, w_std = w_mean[:, None], w_std[:, None]
    denom = np.float32(o.patch**2) * t_std * w_std
    ncc = np.where(denom > 1e-6, num / np.maximum(denom, np.float32(1e-6)), np.float32(0))
    score = _combine(o.weights, ncc, line, ratio(t_mean, w_mean), ratio(t_std, w_std), *extra)
    if score.shape[1] == 1:
        return score[:, 0], ncc[:, 0], np.zeros(score.shape[:1] + score.shape[2:], int)
    k = score.argmax(axis=1)[:, None]
    return np.take_along_axis(score, k, 1)[:, 0], np.take_along_axis(ncc, k, 1)[:, 0], k[:, 0]


def _slide_sum(a: np.ndarray, p: int, skew: int) -> np.ndarray:
    """Sums over j < p of a[..., j * skew, m + j] (skew 1: along diagonals of a (..., p, C)) or of
    a[..., m + j] (skew 0: a box of width p along the last axis), for m in 0..C-p."""
    C = a.shape[-1]
    a = np.ascontiguousarray(a)
    lead = a.shape[:-2] if skew else a.shape[:-1]
    view = np.lib.stride_tricks.as_strided(a, lead + (p, C - p + 1),
                                           a.strides[:len(lead)] + ((skew * C + 1) * a.itemsize, a.itemsize),
                                           writeable=False)
    return view.sum(axis=-2)


def _scan_rows(o: Options, strip, tmpl, rows, line):
    """Scores of the candidates of band rows ``rows`` (R,) (window top rows in the strip), all along
    the strip (N, H, C). tmpl = (mean, std, zero-mean windows (N, S, p, p)); line: the line term,
    broadcast to (N, 1, R, 1). Returns score, ncc, scale index, each (N, R, C - p + 1)."""
    t_mean, t_std, t_zero = tmpl
    (N, S, p, _), H = t_zero.shape, strip.shape[1]
    # A[n, s, r, j, y] = T[n, s, y - rows[r], j]: one product A @ strip gives, for every template
    # column j, that column's dot product with every strip column, summed over the window's rows
    A = np.zeros((N, S, len(rows), p, H), np.float32)
    at = np.arange(len(rows))[:, None], rows[:, None] + np.arange(p)
    A[:, :, at[0], :, at[1]] = t_zero.transpose(2, 0, 1, 3)[None]
    num = _slide_sum((A.reshape(N, -1, H) @ strip).reshape(N, S, len(rows), p, -1), p, 1)
    band = (np.arange(H) >= rows[:, None]) & (np.arange(H) < rows[:, None] + p)
    ones = band.astype(np.float32)                                          # (R, H) row sums
    w_mean = _slide_sum(ones @ strip, p, 0) / np.float32(p * p)
    w_sq = _slide_sum(ones @ (strip * strip), p, 0) / np.float32(p * p)
    w_std = np.sqrt(np.maximum(w_sq - w_mean * w_mean, 0))
    return best_scale(o, (t_mean, t_std), num, w_mean, w_std, line)


def _strip(img2, base, d, n, rows, cols):
    """Samples (N, R, C) of img2 at base + cols d + rows n (offsets in px, windows included)."""
    return sample(img2, *frame_grid(base, d, n, rows, cols))


def _dense_chunk(img2, tmpl, origin, d, n, t_lo, length, o: Options):
    """Dense scan of a chunk of points, coarse to fine: every 1 px along the line on every other
    row of the band, then all rows within 2 px of the best coarse row, 2 px either side of it.
    Returns position along the line (from t_lo), score, ncc, second-best peak (of the coarse scan),
    signed offset across the line, scale index."""
    h, B, p = o.patch // 2, o.band, o.patch
    M = max(int(np.ceil(length.max(initial=0))) + 1, 1)
    base = origin + t_lo[:, None] * d
    half = 2 * (B // 2)                                                     # coarse rows: -half..half
    strip = _strip(img2, base, d, n, np.arange(2 * half + p) - h - half, np.arange(M + p - 1) - h)
    coarse = np.arange(0, 2 * half + 1, 2)
    score = _scan_rows(o, strip, tmpl, coarse, line_term(o, coarse - half)[:, None])[0]
    score = np.where(np.arange(M) > length[:, None, None] + 1e-9, -np.inf, score)
    N = len(strip)
    rc, kc = np.divmod(score.reshape(N, -1).argmax(axis=1), M)
    second = _second_peak(score.max(axis=1), kc, o.exclusion)
    # fine: rows within 2 px of the coarse best (shifted to stay in the band), columns within 2 px
    # (those past the segment's ends masked), sampled afresh so the coarse strip needs no margin
    nr = min(_FINE, 2 * B + 1)
    offsets = np.clip(2 * rc - half - _FINE // 2, -B, B + 1 - nr)[:, None] + np.arange(nr)
    positions = kc[:, None] + np.arange(_FINE) - _FINE // 2
    corner = base + positions[:, :1] * d + offsets[:, :1] * n
    sub = _strip(img2, corner, d, n, np.arange(nr + p - 1) - h, np.arange(_FINE + p - 1) - h)
    fine, ncc, k = _scan_rows(o, sub, tmpl, np.arange(nr), line_term(o, offsets)[:, None, :, None])
    outside = (positions < 0) | (positions > length[:, None] + 1e-9)
    fine = np.where(outside[:, None, :], -np.inf, fine)
    return _pick(fine, ncc, k, offsets, positions, second)


def _second_peak(profile, k, exclusion):
    """Best local maximum of profile (N, M) farther than ``exclusion`` from k (N,): the runner-up,
    not the best peak's own shoulders."""
    padded = np.pad(profile, ((0, 0), (1, 1)), constant_values=-np.inf)
    peaks = (profile >= padded[:, :-2]) & (profile >= padded[:, 2:])
    far = np.abs(np.arange(profile.shape[1])[None, :] - k[:, None]) > exclusion
    return np.where(peaks & far, profile, -np.inf).max(axis=1)


def _parabola(sm, s0, sp):
    """Sub-pixel offset in [-0.5, 0.5] of a parabola's vertex through (-1, sm), (0, s0), (1, sp)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        curv = sm - 2 * s0 + sp
        off = np.where(np.isfinite(sm) & np.isfinite(sp) & (curv < 0), 0.5 * (sm - sp) / curv, 0.0)
    return np.clip(off, -0.5, 0.5)


def _pick(score, ncc, scale, offsets, positions, second):
    """Best of a (N, rows, cols) block of candidates at band ``offsets`` (N, rows) and line
    ``positions`` (N, cols), refined by parabolas; returns what _dense_chunk returns. Across the
    line the line term is part of the score: a match off the line is drawn towards it as much as
    ``line_sigma_px`` says calibration can be trusted."""
    N, nr, nc = score.shape
    idx = np.arange(N)
    r, c = np.divmod(score.reshape(N, -1).argmax(axis=1), nc)
    best = score[idx, r, c]
    padded = np.pad(score, ((0, 0), (1, 1), (1, 1)), constant_values=-np.inf)
    along = _parabola(padded[idx, r + 1, c], best, padded[idx, r + 1, c + 2])
    across = _parabola(padded[idx, r, c + 1], best, padded[idx, r + 2, c + 1])
    cross = offsets[idx, r] + across
    return positions[idx, c] + along, best, ncc[idx, r, c], second, cross, scale[idx, r, c]


def _chunks(length: np.ndarray, floats_per_px: int):
    """Index arrays splitting the points into chunks of like segment lengths (so strips are hardly
    padded to the longest), each holding about _CHUNK_FLOATS of strips and products: small enough
    to stay in cache, large enough that numpy's per-call overhead does not count."""
    order = np.argsort(-length, kind="stable")                  # longest first: it sizes its chunk
    start = 0
    while start < len(order):
        step = max(1, int(_CHUNK_FLOATS // (floats_per_px * np.ceil(length[order[start]] + 1))))
        yield order[start:start + step]
        start += step


def dense(img2, tmpl, origin, d, n, t_lo, t_hi, o: Options, scales) -> Found:
    """Best candidate of each point along its segment [t_lo, t_hi]; tmpl = image-1 windows (N, S, p, p)."""
    N = len(tmpl)
    out = Found(np.full((N, 2), np.nan), np.full(N, -np.inf), np.zeros(N), np.full(N, -np.inf),
                np.zeros(N), np.ones(N))
    t_stats = stats(tmpl)
    length = t_hi - t_lo
    # floats per px of strip: its rows, and as many again per scale for the template-by-strip products
    for at in _chunks(length + o.patch, (2 * o.band + o.patch) * (1 + len(scales))):
        t, best, ncc, second, cross, k = _dense_chunk(img2, tuple(v[at] for v in t_stats), origin[at], d[at],
                                                      n[at], t_lo[at], length[at], o)
        out.pts2[at] = origin[at] + (t_lo[at] + t)[:, None] * d[at] + cross[:, None] * n[at]
        out.score[at], out.ncc[at], out.second[at] = best, ncc, second
        out.line[at], out.scale[at] = np.abs(cross), scales[k]
    return out
