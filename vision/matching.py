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

Geometry (``vision.match_geometry``). Each window is sampled (bilinear, cv2.remap) in a frame turned
to its own epipolar line, which is stereo rectification done locally, so a dense scan
(``vision.match_scan``) is one strip per point along its line in image 2: candidate windows are the
strip's sliding windows, their NCC numerators one batched matrix product, their means and contrasts
row sums boxed along the line. Candidates lie every 1 px along the line and at whole-pixel offsets
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

from vision.match_geometry import inside_span, line_frames, segments_by_offset, segments_by_range, windows
from vision.match_scan import Found, Options, best_scale, dense, line_term, ratio, stats

__all__ = ["MatchResult", "Reject", "Weights", "match_points", "segments_by_offset", "segments_by_range"]


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


def _feature_terms(f1, f2, order, idx):
    """Size and orientation similarities (N, K) of each point's candidates; features (., 2) hold
    (size_px, angle_rad)."""
    f2 = np.asarray(f2, dtype=float)[order]
    f1 = np.asarray(f1, dtype=float)[idx][:, None, :]
    return ratio(f1[..., 0], f2[..., 0]), 0.5 * (1 + np.cos(f1[..., 1] - f2[..., 1]))


def _features(img2, tmpl, frame, t_lo, t_hi, cands, feats, o: Options, band_px, idx, scales) -> Found:
    """Best of the candidate points (M2, 2) inside each point's band and span."""
    lines, d, n, origin = frame
    h, N = o.patch // 2, len(tmpl)
    dist = lines[:, :2] @ cands.T + lines[:, 2:]                            # (N, M2) signed, px
    along = np.einsum("nd,nmd->nm", d, cands[None] - origin[:, None])
    ok = (np.abs(dist) <= band_px) & (along >= t_lo[:, None]) & (along <= t_hi[:, None])
    K = max(int(ok.sum(axis=1).max(initial=0)), 1)
    order = np.argsort(~ok, axis=1, kind="stable")[:, :K]                   # in-band candidates first
    sel = np.take_along_axis(ok, order, axis=1)
    win = windows(img2, cands[order], d[:, None], n[:, None], h)           # (N, K, p, p)
    c_mean, c_std, c_zero = stats(win)
    t_mean, t_std, t_zero = stats(tmpl)
    dsel = np.take_along_axis(dist, order, axis=1)
    line = line_term(o, dsel)[:, None]
    extra = [t[:, None] for t in _feature_terms(*feats, order, idx)] if feats[0] is not None else []
    num = np.einsum("nkij,nsij->nsk", c_zero, t_zero)
    score, ncc, k = best_scale(o, (t_mean, t_std), num, c_mean, c_std, line, extra)
    score = np.where(sel, score, -np.inf)
    rows = np.arange(N)
    j = score.argmax(axis=1)
    chosen = order[rows, j]
    gap = np.linalg.norm(cands[order] - cands[chosen][:, None], axis=2)
    second = np.where(gap > o.exclusion, score, -np.inf).max(axis=1)
    found = sel.any(axis=1)
    return Found(np.where(found[:, None], cands[chosen], np.nan), score[rows, j], ncc[rows, j], second,
                 np.abs(dsel[rows, j]), scales[k[rows, j]], np.where(found, chosen, -1))


def _refine(img2, tmpl, frame, t_lo, t_hi, found: Found, refine_px, o: Options, scales) -> Found:
    """Dense scan +-refine_px along the line around each chosen candidate; keeps its score."""
    _, d, n, origin = frame
    t = np.einsum("nd,nd->n", d, found.pts2 - origin)
    has = np.isfinite(t)
    lo = np.where(has, np.maximum(t_lo, t - refine_px), 1.0)
    hi = np.where(has, np.minimum(t_hi, t + refine_px), 0.0)
    fine = dense(img2, tmpl, origin, d, n, lo, hi, o, scales)
    better = has & (lo <= hi) & np.isfinite(fine.pts2[:, 0])
    found.pts2 = np.where(better[:, None], fine.pts2, found.pts2)
    found.line = np.where(better, fine.line, found.line)
    return found


def _empty(N: int) -> MatchResult:
    return MatchResult(np.full((N, 2), np.nan), np.full(N, -np.inf), np.zeros(N), np.full(N, -np.inf),
                       np.full(N, np.nan), np.full(N, np.nan), np.full(N, -1),
                       np.full(N, Reject.OUTSIDE, dtype=np.int8))


def _fill(res: MatchResult, work, f: Found, o: Options):
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
    o = Options(patch, int(np.floor(band_px)), weights, line_sigma_px, min_ncc, ambiguity_margin,
                h if exclusion_px is None else int(exclusion_px))
    lines, d, n, origin, d1, n1 = line_frames(F, pts1)
    t_lo, t_hi = inside_span(origin, d, n, img2.shape, h, h + int(np.ceil(band_px)))
    if segments is not None:
        ends = np.einsum("nd,nkd->nk", d, np.asarray(segments, float).reshape(N, 2, 2) - origin[:, None])
        t_lo, t_hi = np.maximum(t_lo, ends.min(axis=1)), np.minimum(t_hi, ends.max(axis=1))
    ext1 = h / scales.min() * (np.abs(d1) + np.abs(n1))
    in1 = np.all((pts1 >= ext1) & (pts1 <= np.array(img1.shape[::-1]) - 1 - ext1), axis=1)
    work = np.flatnonzero(in1 & (t_lo <= t_hi))
    # image-1 windows at 1/s px steps see what an image-2 window of 1 px steps sees when s x larger
    inv = (1 / scales)[None, :, None]
    tmpl = windows(img1, pts1[work][:, None], d1[work][:, None] * inv, n1[work][:, None] * inv, h)
    flat = tmpl.std(axis=(2, 3)).max(axis=1) < min_contrast
    res.reason[work[flat]] = Reject.FLAT
    work, tmpl = work[~flat], tmpl[~flat]
    frame = (lines[work], d[work], n[work], origin[work])
    if candidates is None:
        found = dense(img2, tmpl, origin[work], d[work], n[work], t_lo[work], t_hi[work], o, scales)
    else:
        cands = np.asarray(candidates, dtype=float).reshape(-1, 2)
        found = _features(img2, tmpl, frame, t_lo[work], t_hi[work], cands, (features1, features2), o,
                          band_px, work, scales)
        if refine_px > 0:
            found = _refine(img2, tmpl, frame, t_lo[work], t_hi[work], found, refine_px, o, scales)
    _fill(res, work, found, o)
    return res
