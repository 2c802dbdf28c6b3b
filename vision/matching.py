"""Stereo matching along epipolar bands (paper section 3.2), vectorised over points and candidates.

For a point of image 1 the match in image 2 maximises a combined similarity of
  * zero-mean normalised cross-correlation of two ``patch`` x ``patch`` windows (eq. 5),
  * distance of the candidate to the epipolar line,
  * similarity of local illumination: the windows' mean and contrast (standard deviation),
  * for features (fins): similarity of size and of orientation.

Eq. (5) is the plain normalised correlation sum(I1 I2) / sqrt(sum I1^2 sum I2^2). On images that are
never negative it stays close to 1 for any two bright windows, so it hardly discriminates. We use its
zero-mean form (each window minus its mean): it is invariant to gain *and* offset between the cameras,
which is what eq. (5) is there for. That invariance also lets a look-alike patch under very different
lighting score as high as the true one, so the mean/contrast terms bring the illumination back in, with
a small weight, as the paper's "similarity in the local illumination conditions".

Each term is a similarity in [0, 1] (NCC in [-1, 1]); the score is their weighted mean (``Weights``).

Geometry. Each window is sampled (bilinear, cv2.remap) in a frame turned to its own epipolar line,
which is stereo rectification done locally, so a dense scan is one strip per point along its line
in image 2: candidate windows are the strip's sliding windows, NCC is one einsum, window means and
contrasts come from box filters. Candidates lie every 1 px along the line and at whole-pixel offsets
up to ``band_px`` across it, searched coarse to fine (every other offset along the whole segment,
then every offset near the best: a match 1 px off the line still peaks at the same place on it);
the best is refined by a parabola through its score and its neighbours', along and across.
``scales`` also tries image-1 windows resampled for structures seen larger or smaller by camera 2
(a convergent rig's foreshortening).

Pixels follow OpenCV's convention. Images must be undistorted if the calibration has distortion.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import cv2
import numpy as np

from vision.epipolar import epipolar_lines

_STRIP_BUDGET = 4_000_000      # samples per chunk of points: bounds memory on long (whole-line) scans
_REMAP_ROWS = 32_000           # cv2.remap refuses maps of SHRT_MAX rows or more


class Reject(IntEnum):
    """Why a point has no valid match (``MatchResult.reason``)."""

    OK = 0
    OUTSIDE = 1        # its window leaves image 1, or no part of its search segment lies in image 2
    FLAT = 2           # its window has no texture (contrast < min_contrast): NCC is undefined
    NO_CANDIDATE = 3   # feature mode: no candidate feature within the band and span
    LOW_SCORE = 4      # best NCC below min_ncc
    AMBIGUOUS = 5      # the second-best peak scores within ambiguity_margin of the best


@dataclass(frozen=True)
class Weights:
    """Weights of the combined similarity (the score is the weighted mean of the terms).

    NCC dominates: texture is the evidence. The line term (Gaussian of the distance in units of
    ``line_sigma_px``) absorbs calibration error without letting a candidate far off the line win.
    Mean (min/max of the window means) and contrast (min/max of the window standard deviations) are
    ratios, so a moderate gain difference between the cameras costs little but a look-alike under
    light three times brighter is penalised. Size and orientation (min/max of the sizes;
    (1 + cos of the angle difference) / 2) only count in feature mode.
    """

    ncc: float = 1.0
    line: float = 0.25
    mean: float = 0.15
    contrast: float = 0.15
    size: float = 0.2
    orientation: float = 0.2


@dataclass
class MatchResult:
    """Per point of image 1 (N rows). ``pts2`` is NaN where no candidate could be scored."""

    pts2: np.ndarray        # (N, 2) float64, sub-pixel position in image 2
    score: np.ndarray       # (N,) combined similarity of the best candidate
    ncc: np.ndarray         # (N,) its zero-mean NCC
    second: np.ndarray      # (N,) score of the second-best peak (-inf if none)
    line_px: np.ndarray     # (N,) distance of pts2 to the epipolar line
    scale: np.ndarray       # (N,) which of ``scales`` fitted best
    index: np.ndarray       # (N,) int, feature mode: row of the chosen candidate, else -1
    reason: np.ndarray      # (N,) int8, Reject codes

    @property
    def valid(self) -> np.ndarray:
        return self.reason == Reject.OK


def _grey(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return np.ascontiguousarray(img, dtype=np.float32)


def _unit_dirs(lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (N, 2) of lines (N, 3) and normals (the directions turned +90 degrees)."""
    d = np.c_[lines[:, 1], -lines[:, 0]]
    d /= np.hypot(d[:, 0], d[:, 1])[:, None]
    return d, np.c_[-d[:, 1], d[:, 0]]


def _line_frames(F: np.ndarray, pts1: np.ndarray):
    """Per point: its epipolar line in image 2 (N, 3, a^2 + b^2 = 1), the line's direction d2 and
    normal n2, the origin of positions along it (the foot of pts1's own coordinates), and the
    direction d1 / normal n1 of the matching epipolar line through pts1 in image 1.

    Windows are sampled in these frames, which is stereo rectification done locally: a plane's
    homography maps l1 onto l2, so the local map between the windows has no rotation left. d2
    points to +u (+v when vertical); d1 is signed to agree with it, which assumes the cameras are
    not rolled by more than 90 degrees relative to each other.
    """
    lines = epipolar_lines(F, pts1)
    d2, n2 = _unit_dirs(lines)
    flip = (d2[:, 0] < 0) | ((d2[:, 0] == 0) & (d2[:, 1] < 0))
    d2[flip] *= -1
    n2[flip] *= -1
    offset = lines[:, 0] * pts1[:, 0] + lines[:, 1] * pts1[:, 1] + lines[:, 2]
    origin = pts1 - offset[:, None] * lines[:, :2]
    d1, n1 = _unit_dirs(np.c_[origin, np.ones(len(origin))] @ F)        # l1 = F^T x2, x2 on l2
    flip = np.einsum("nd,nd->n", d1, d2) < 0
    d1[flip] *= -1
    n1[flip] *= -1
    return lines, d2, n2, origin, d1, n1


def segments_by_offset(pts1: np.ndarray, F: np.ndarray, lo_px: float, hi_px: float) -> np.ndarray:
    """Search segments (N, 2, 2) on the epipolar lines of pts1 (N, 2): from ``lo_px`` to ``hi_px``
    along the line from the foot of pts1's own coordinates, positive towards +u (+v if vertical).
    For cameras side by side (camera 2 on the right), the offset is minus the disparity u1 - u2."""
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    _, d, _, origin, _, _ = _line_frames(F, pts1)
    return np.stack([origin + lo_px * d, origin + hi_px * d], axis=1)


def segments_by_range(P1: np.ndarray, P2: np.ndarray, pts1: np.ndarray, near_mm: float | np.ndarray,
                      far_mm: float | np.ndarray) -> np.ndarray:
    """Search segments (N, 2, 2) in image 2: images of the points of pts1's lines of sight between
    ``near_mm`` and ``far_mm`` (scalars or (N,)) from camera 1's centre: a rig's working distance."""
    P1 = np.asarray(P1, dtype=float)
    P2 = np.asarray(P2, dtype=float)
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    M1 = P1[:, :3]
    centre = -np.linalg.solve(M1, P1[:, 3])
    rays = np.linalg.solve(M1, np.c_[pts1, np.ones(len(pts1))].T).T
    # X = C + lam * ray images to lam * (u, v, 1): it is in front of camera 1 when lam * det(M1) > 0
    rays *= np.sign(np.linalg.det(M1)) / np.linalg.norm(rays, axis=1)[:, None]
    ends = []
    for dist in (near_mm, far_mm):
        dist = np.broadcast_to(np.asarray(dist, dtype=float), (len(pts1),))[:, None]
        x = (centre + dist * rays) @ P2[:, :3].T + P2[:, 3]
        ends.append(x[:, :2] / x[:, 2:])
    return np.stack(ends, axis=1)


def _inside_span(origin, d, n, shape, along, across):
    """Interval [t_lo, t_hi] (N,) of centres origin + t d whose rotated window (half-sizes ``along``
    on d, ``across`` on n) stays inside an image of ``shape``; empty where t_lo > t_hi."""
    ext = along * np.abs(d) + across * np.abs(n)
    t_lo = np.full(len(d), -np.inf)
    t_hi = np.full(len(d), np.inf)
    for axis, size in ((0, shape[1]), (1, shape[0])):
        lo, hi = ext[:, axis], size - 1 - ext[:, axis]
        o, step = origin[:, axis], d[:, axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = (lo - o) / step, (hi - o) / step
        flat = np.abs(step) < 1e-12
        inside = (o >= lo) & (o <= hi)
        t_lo = np.maximum(t_lo, np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(a, b)))
        t_hi = np.minimum(t_hi, np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(a, b)))
    return t_lo, t_hi


def _sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of img at float positions of any shape (leading axes kept)."""
    shape, total = x.shape, x.size
    cols = shape[-1]
    for size in shape[-2::-1]:          # fold trailing axes until the map has few enough rows
        if total // cols < _REMAP_ROWS or cols * size >= _REMAP_ROWS:
            break
        cols *= size
    x, y = (v.reshape(-1, cols).astype(np.float32, copy=False) for v in (x, y))
    out = [cv2.remap(img, x[r:r + _REMAP_ROWS], y[r:r + _REMAP_ROWS], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE) for r in range(0, len(x), _REMAP_ROWS)]
    return np.concatenate(out).reshape(shape)


def _windows(img, centres, d, n, h):
    """Windows (..., p, p) of img, rows along n and columns along d, centred on centres (..., 2);
    d and n broadcast against centres."""
    a = np.arange(-h, h + 1, dtype=np.float32)
    c, dd, nn = (np.asarray(v, np.float32)[..., None, None, :] for v in (centres, d, n))
    x, y = (c[..., i] + a[None, :] * dd[..., i] + a[:, None] * nn[..., i] for i in (0, 1))
    return _sample(img, x, y)


def _stats(win: np.ndarray):
    """Mean, standard deviation and zero-mean copy of windows (..., p, p)."""
    mean = win.mean(axis=(-2, -1))
    zero = win - mean[..., None, None]
    std = np.sqrt((zero * zero).mean(axis=(-2, -1)))
    return mean, std, zero


def _ratio(a, b):
    """min/max of two non-negative quantities, in [0, 1]."""
    return np.minimum(a, b) / np.maximum(np.maximum(a, b), np.float32(1e-6))


def _combine(w: Weights, ncc, line, mean, contrast, size=None, orientation=None):
    terms = [(w.ncc, ncc), (w.line, line), (w.mean, mean), (w.contrast, contrast)]
    if size is not None:
        terms += [(w.size, size), (w.orientation, orientation)]
    total = sum(weight for weight, _ in terms)
    return sum(weight * term for weight, term in terms) / total


def _parabola(sm, s0, sp):
    """Sub-pixel offset in [-0.5, 0.5] of a parabola's vertex through (-1, sm), (0, s0), (1, sp)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        curv = sm - 2 * s0 + sp
        off = np.where(np.isfinite(sm) & np.isfinite(sp) & (curv < 0), 0.5 * (sm - sp) / curv, 0.0)
    return np.clip(off, -0.5, 0.5)


@dataclass(frozen=True)
class _Options:
    patch: int
    band: int
    weights: Weights
    line_sigma: float
    min_ncc: float
    margin: float
    exclusion: int


@dataclass
class _Found:
    """Best candidate per point (arrays over the points being matched)."""

    pts2: np.ndarray
    score: np.ndarray
    ncc: np.ndarray
    second: np.ndarray
    line: np.ndarray
    scale: np.ndarray
    index: np.ndarray | None = None


def _best_scale(o: _Options, tmpl_stats, num, w_mean, w_std, line, extra=()):
    """Scores of candidates against templates at S scales, the best scale kept.

    tmpl_stats (mean, std): (N, S); num, the NCC numerators: (N, S, *C); window mean/std: (N, *C);
    line and extra terms broadcast to (N, 1, *C). Returns score, ncc, scale index, each (N, *C)."""
    pad = (slice(None), slice(None)) + (None,) * (num.ndim - 2)
    t_mean, t_std = (t[pad] for t in tmpl_stats)
    w_mean, w_std = w_mean[:, None], w_std[:, None]
    denom = np.float32(o.patch**2) * t_std * w_std
    ncc = np.where(denom > 1e-6, num / np.maximum(denom, np.float32(1e-6)), np.float32(0))
    score = _combine(o.weights, ncc, line, _ratio(t_mean, w_mean), _ratio(t_std, w_std), *extra)
    if score.shape[1] == 1:
        return score[:, 0], ncc[:, 0], np.zeros(score.shape[:1] + score.shape[2:], int)
    k = score.argmax(axis=1)[:, None]
    return np.take_along_axis(score, k, 1)[:, 0], np.take_along_axis(ncc, k, 1)[:, 0], k[:, 0]


def _line_term(o: _Options, offsets):
    return np.exp(-0.5 * (np.asarray(offsets, np.float32) / o.line_sigma) ** 2)


def _dense_chunk(img2, tmpl, origin, d, n, t_lo, length, o: _Options):
    """Dense scan of a chunk of points, coarse to fine: every 1 px along the line on every other
    row of the band, then all rows within 2 px of the best coarse row, 2 px either side of it.
    Returns position along the line (from t_lo), score, ncc, second-best peak (of the coarse scan),
    signed offset across the line, scale index."""
    h, B, p = o.patch // 2, o.band, o.patch
    M = max(int(np.ceil(length.max(initial=0))) + 1, 1)
    cols = (np.arange(M + p - 1) - h).astype(np.float32)[None, None, :]
    rows = (np.arange(2 * B + p) - h - B).astype(np.float32)[None, :, None]
    base = (origin + t_lo[:, None] * d).astype(np.float32)[:, None, None, :]
    d32, n32 = d.astype(np.float32)[:, None, None, :], n.astype(np.float32)[:, None, None, :]
    x, y = (base[..., i] + cols * d32[..., i] + rows * n32[..., i] for i in (0, 1))
    strip = _sample(img2, x, y)                                             # (N, 2B+p, M+p-1)
    t_mean, t_std, t_zero = _stats(tmpl)
    view = np.lib.stride_tricks.sliding_window_view(strip, (p, p), axis=(1, 2))   # (N, 2B+1, M, p, p)
    # window means and mean squares: box filters over the stacked strips, read where a window
    # lies inside its own point's strip
    flat = strip.reshape(-1, strip.shape[2])
    inner = (slice(None), slice(h, h + 2 * B + 1), slice(h, h + M))
    w_mean = cv2.boxFilter(flat, -1, (p, p)).reshape(strip.shape)[inner]
    w_std = np.sqrt(np.maximum(cv2.sqrBoxFilter(flat, -1, (p, p)).reshape(strip.shape)[inner] - w_mean**2, 0))
    half = 2 * (B // 2)
    coarse = slice(B - half, B + half + 1, 2)
    num = np.einsum("nbmij,nsij->nsbm", view[:, coarse], t_zero)            # sum T~ W = sum T~ (W - mean W)
    line = _line_term(o, np.arange(-half, half + 1, 2))[None, None, :, None]
    score, _, _ = _best_scale(o, (t_mean, t_std), num, w_mean[:, coarse], w_std[:, coarse], line)
    score = np.where(np.arange(M) > length[:, None, None] + 1e-9, -np.inf, score)
    N, idx = len(tmpl), np.arange(len(tmpl))
    rc, kc = np.divmod(score.reshape(N, -1).argmax(axis=1), M)
    second = _second_peak(score.max(axis=1), kc, o.exclusion)
    fr = (B - half + 2 * rc)[:, None] + np.arange(-2, 3)                   # fine rows (N, 5)
    fk = kc[:, None] + np.arange(-2, 3)                                     # fine columns (N, 5)
    frc, fkc = np.clip(fr, 0, 2 * B), np.clip(fk, 0, M - 1)
    at = (idx[:, None, None], frc[:, :, None], fkc[:, None, :])
    num = np.einsum("nrcij,nsij->nsrc", view[at], t_zero)
    fine, ncc, k = _best_scale(o, (t_mean, t_std), num, w_mean[at], w_std[at],
                               _line_term(o, frc - B)[:, None, :, None])
    ok = ((fr >= 0) & (fr <= 2 * B))[:, :, None] & ((fk >= 0) & (fk <= length[:, None] + 1e-9))[:, None, :]
    return _pick(np.where(ok, fine, -np.inf), ncc, k, fr - B, fk, second)


def _second_peak(profile, k, exclusion):
    """Best local maximum of profile (N, M) farther than ``exclusion`` from k (N,): the runner-up,
    not the best peak's own shoulders."""
    padded = np.pad(profile, ((0, 0), (1, 1)), constant_values=-np.inf)
    peaks = (profile >= padded[:, :-2]) & (profile >= padded[:, 2:])
    far = np.abs(np.arange(profile.shape[1])[None, :] - k[:, None]) > exclusion
    return np.where(peaks & far, profile, -np.inf).max(axis=1)


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


def _dense(img2, tmpl, origin, d, n, t_lo, t_hi, o: _Options, scales) -> _Found:
    """Best candidate of each point along its segment [t_lo, t_hi]."""
    N = len(tmpl)
    out = _Found(np.full((N, 2), np.nan), np.full(N, -np.inf), np.zeros(N), np.full(N, -np.inf),
                 np.zeros(N), np.ones(N))
    length = t_hi - t_lo
    rows = 2 * o.band + o.patch
    per_point = rows * (np.ceil(length.max(initial=0)) + o.patch) * len(scales)
    step = int(max(1, min(_STRIP_BUDGET // per_point, _REMAP_ROWS // rows)))
    for s in range(0, N, step):        # chunks of points, only to bound memory on long scans
        sl = slice(s, s + step)
        t, best, ncc, second, cross, k = _dense_chunk(img2, tmpl[sl], origin[sl], d[sl], n[sl], t_lo[sl],
                                                      length[sl], o)
        out.pts2[sl] = origin[sl] + (t_lo[sl] + t)[:, None] * d[sl] + cross[:, None] * n[sl]
        out.score[sl], out.ncc[sl], out.second[sl] = best, ncc, second
        out.line[sl], out.scale[sl] = np.abs(cross), scales[k]
    return out


def _feature_terms(f1, f2, order, idx):
    """Size and orientation similarities (N, K) of each point's candidates; features (., 2) hold
    (size_px, angle_rad)."""
    f2 = np.asarray(f2, dtype=float)[order]
    f1 = np.asarray(f1, dtype=float)[idx][:, None, :]
    return _ratio(f1[..., 0], f2[..., 0]), 0.5 * (1 + np.cos(f1[..., 1] - f2[..., 1]))


def _features(img2, tmpl, frame, t_lo, t_hi, cands, feats, o: _Options, band_px, idx, scales) -> _Found:
    """Best of the candidate points (M2, 2) inside each point's band and span."""
    lines, d, n, origin = frame
    h, N = o.patch // 2, len(tmpl)
    dist = lines[:, :2] @ cands.T + lines[:, 2:]                            # (N, M2) signed, px
    along = np.einsum("nd,nmd->nm", d, cands[None] - origin[:, None])
    ok = (np.abs(dist) <= band_px) & (along >= t_lo[:, None]) & (along <= t_hi[:, None])
    K = max(int(ok.sum(axis=1).max(initial=0)), 1)
    order = np.argsort(~ok, axis=1, kind="stable")[:, :K]                   # in-band candidates first
    sel = np.take_along_axis(ok, order, axis=1)
    win = _windows(img2, cands[order], d[:, None], n[:, None], h)           # (N, K, p, p)
    c_mean, c_std, c_zero = _stats(win)
    t_mean, t_std, t_zero = _stats(tmpl)
    dsel = np.take_along_axis(dist, order, axis=1)
    line = _line_term(o, dsel)[:, None]
    extra = [t[:, None] for t in _feature_terms(*feats, order, idx)] if feats[0] is not None else []
    num = np.einsum("nkij,nsij->nsk", c_zero, t_zero)
    score, ncc, k = _best_scale(o, (t_mean, t_std), num, c_mean, c_std, line, extra)
    score = np.where(sel, score, -np.inf)
    rows = np.arange(N)
    j = score.argmax(axis=1)
    chosen = order[rows, j]
    gap = np.linalg.norm(cands[order] - cands[chosen][:, None], axis=2)
    second = np.where(gap > o.exclusion, score, -np.inf).max(axis=1)
    found = sel.any(axis=1)
    return _Found(np.where(found[:, None], cands[chosen], np.nan), score[rows, j], ncc[rows, j], second,
                  np.abs(dsel[rows, j]), scales[k[rows, j]], np.where(found, chosen, -1))


def _refine(img2, tmpl, frame, t_lo, t_hi, found: _Found, refine_px, o: _Options, scales) -> _Found:
    """Dense scan +-refine_px along the line around each chosen candidate; keeps its score."""
    _, d, n, origin = frame
    t = np.einsum("nd,nd->n", d, found.pts2 - origin)
    has = np.isfinite(t)
    lo = np.where(has, np.maximum(t_lo, t - refine_px), 1.0)
    hi = np.where(has, np.minimum(t_hi, t + refine_px), 0.0)
    fine = _dense(img2, tmpl, origin, d, n, lo, hi, o, scales)
    better = has & (lo <= hi) & np.isfinite(fine.pts2[:, 0])
    found.pts2 = np.where(better[:, None], fine.pts2, found.pts2)
    found.line = np.where(better, fine.line, found.line)
    return found


def _empty(N: int) -> MatchResult:
    return MatchResult(np.full((N, 2), np.nan), np.full(N, -np.inf), np.zeros(N), np.full(N, -np.inf),
                       np.full(N, np.nan), np.full(N, np.nan), np.full(N, -1),
                       np.full(N, Reject.OUTSIDE, dtype=np.int8))


def _fill(res: MatchResult, work, f: _Found, o: _Options):
    res.pts2[work], res.score[work], res.ncc[work] = f.pts2, f.score, f.ncc
    res.second[work], res.line_px[work], res.scale[work] = f.second, f.line, f.scale
    if f.index is not None:
        res.index[work] = f.index
    reason = np.full(len(work), Reject.OK, dtype=np.int8)
    reason[f.second >= f.score - o.margin] = Reject.AMBIGUOUS
    reason[f.ncc < o.min_ncc] = Reject.LOW_SCORE
    reason[~np.isfinite(f.score)] = Reject.NO_CANDIDATE
    res.reason[work] = reason


def match_points(img1: np.ndarray, img2: np.ndarray, pts1: np.ndarray, F: np.ndarray, *,
                 segments: np.ndarray | None = None, candidates: np.ndarray | None = None,
                 features1: np.ndarray | None = None, features2: np.ndarray | None = None,
                 patch: int = 11, band_px: float = 1.0, scales: tuple[float, ...] = (1.0,),
                 weights: Weights = Weights(), line_sigma_px: float = 1.0, min_ncc: float = 0.7,
                 ambiguity_margin: float = 0.05, exclusion_px: int | None = None,
                 min_contrast: float = 1.0, refine_px: int = 2) -> MatchResult:
    """Match points (N, 2) of img1 (H1, W1[, C]) along their epipolar bands in img2 (H2, W2[, C]).

    F (3, 3): x2^T F x1 = 0. ``segments`` (N, 2, 2): the part of each line to search (endpoints
    are projected onto the line), e.g. from ``segments_by_range``; default the whole line inside
    img2. Dense scan by default: every 1 px along the line, whole-pixel offsets up to ``band_px``
    across it. With ``candidates`` (M2, 2) only those points of img2 within ``band_px`` of the line
    are scored (detected fins to detected fins); ``features1`` (N, 2) / ``features2`` (M2, 2) =
    (size_px, angle_rad) add the size and orientation terms; the chosen candidate is then refined
    by a dense scan +-``refine_px`` along the line (0: keep the candidate's own position).
    ``patch``: odd window side (px). ``scales``: sizes of image-2 structures relative to image 1
    to try (a convergent rig sees a surface up to ~1.3x larger in one camera near the image edges);
    each costs one more NCC pass. A match is rejected when its NCC < ``min_ncc`` or when the
    second-best peak more than ``exclusion_px`` (default patch // 2) away scores within
    ``ambiguity_margin`` of it. ``min_contrast``: least standard deviation of the img1 window, in
    grey levels, for it to count as textured.
    """
    if patch < 3 or patch % 2 == 0:
        raise ValueError(f"patch must be odd and >= 3, got {patch}")
    if (features1 is None) != (features2 is None) or (features1 is not None and candidates is None):
        raise ValueError("features1 and features2 go together, with candidates")
    scales = np.asarray(scales, dtype=float).reshape(-1)
    if len(scales) == 0 or np.any(scales <= 0):
        raise ValueError(f"scales must be positive, got {scales}")
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    N, h = len(pts1), patch // 2
    res = _empty(N)
    if N == 0:
        return res
    img1, img2 = _grey(img1), _grey(img2)
    o = _Options(patch, int(np.floor(band_px)), weights, line_sigma_px, min_ncc, ambiguity_margin,
                 h if exclusion_px is None else int(exclusion_px))
    lines, d, n, origin, d1, n1 = _line_frames(F, pts1)
    t_lo, t_hi = _inside_span(origin, d, n, img2.shape, h, h + int(np.ceil(band_px)))
    if segments is not None:
        ends = np.einsum("nd,nkd->nk", d, np.asarray(segments, float).reshape(N, 2, 2) - origin[:, None])
        t_lo, t_hi = np.maximum(t_lo, ends.min(axis=1)), np.minimum(t_hi, ends.max(axis=1))
    ext1 = h / scales.min() * (np.abs(d1) + np.abs(n1))
    in1 = np.all((pts1 >= ext1) & (pts1 <= np.array(img1.shape[::-1]) - 1 - ext1), axis=1)
    work = np.flatnonzero(in1 & (t_lo <= t_hi))
    # image-1 windows at 1/s px steps see what an image-2 window of 1 px steps sees when s x larger
    inv = (1 / scales)[None, :, None]
    tmpl = _windows(img1, pts1[work][:, None], d1[work][:, None] * inv, n1[work][:, None] * inv, h)
    flat = tmpl.std(axis=(2, 3)).max(axis=1) < min_contrast
    res.reason[work[flat]] = Reject.FLAT
    work, tmpl = work[~flat], tmpl[~flat]
    frame = (lines[work], d[work], n[work], origin[work])
    if candidates is None:
        found = _dense(img2, tmpl, origin[work], d[work], n[work], t_lo[work], t_hi[work], o, scales)
    else:
        cands = np.asarray(candidates, dtype=float).reshape(-1, 2)
        found = _features(img2, tmpl, frame, t_lo[work], t_hi[work], cands, (features1, features2), o,
                          band_px, work, scales)
        if refine_px > 0:
            found = _refine(img2, tmpl, frame, t_lo[work], t_hi[work], found, refine_px, o, scales)
    _fill(res, work, found, o)
    return res
