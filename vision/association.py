"""Stereo association (paper section 4.3): forks matched across the pair, triangulated, each paired
with its own fish's snout in 3-D by the species geometry, incoherent lengths dropped, and a
quality score per fish from what the measurement rests on.

Forks are detected in both images, so matching is epipolar pairing of detections: a right fork is a
candidate for a left one when it lies within ``band_px`` of the left fork's epipolar line, has a
similar axis angle and fin span; the evidence is the zero-mean NCC of the two
forks' neighbourhoods, each sampled in its own frame (axis, span), so the views' different scale
and roll cost nothing. Pairs are taken best first, each fork at most once.

Snout candidates (``vision.snout``) from both images are triangulated in every combination; a
combination is a fish when its epipolar residual is small, its length is in the species' range and
its axis is within ``max_tilt_deg`` of the water surface (the body near-parallel to it). The
orientation check is built in: each image's snout is searched ahead of its own fork, along its own
fin's axis, so the 3-D snout lies on the same side of the fork in both views or not at all.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from vision.calib_file import StereoCalibration
from vision.epipolar import epipolar_lines, fundamental_from_projections
from vision.fins import Fins, sample_frames, sample_frames_raw
from vision.match_geometry import segments_by_range
from vision.triangulation import normalise_projection, triangulate_calibrated, undistort_pixels

PATCH = 15


@dataclass
class View:
    """What one image contributes: located forks and the grey pyramid they were located on."""

    pyr: list[np.ndarray]
    fins: Fins
    fish_level: np.ndarray
    water_level: np.ndarray
    arm_rms: np.ndarray
    comps: list = field(default_factory=list)       # silhouettes' (labels, stats) on the working image
    scale: tuple[float, float] = (1.0, 1.0)         # full-resolution px per working px
    confidence: np.ndarray | None = None            # (N,) the learned locator's, 0..1 (None: not used)

    def sure(self) -> np.ndarray:
        """Each fork's confidence (1 where the learned locator did not place it)."""
        return np.ones(len(self.fins)) if self.confidence is None else self.confidence


@dataclass
class ForkPairs:
    i: np.ndarray           # (M,) left fork index
    j: np.ndarray           # (M,) right fork index
    ncc: np.ndarray         # (M,)
    line_px: np.ndarray     # (M,) distance of the right fork to the left one's epipolar line


def camera_frame(P: np.ndarray) -> tuple[float, np.ndarray]:
    """Focal length (px) of a camera and the world direction of its image-up."""
    K, R, _, _, _, _, _ = cv2.decomposeProjectionMatrix(np.asarray(P, float))
    K = K / K[2, 2]
    signs = np.sign(np.diag(K))
    signs[signs == 0] = 1
    K, R = K * signs, (R.T * signs).T            # K with a positive diagonal
    return float(0.5 * (abs(K[0, 0]) + abs(K[1, 1]))), -R[1] / np.linalg.norm(R[1])


def _patches(v: View, f: Fins | None = None) -> np.ndarray:
    """Zero-mean unit vectors (N, PATCH^2 C) of each fork's neighbourhood in its own frame."""
    f = v.fins if f is None else f
    t = np.linspace(-0.5, 0.5, PATCH)
    C = v.pyr[0].shape[2] if v.pyr[0].ndim == 3 else 1
    step = f.span_px / PATCH
    lev = np.clip(np.floor(np.log2(np.maximum(step, 1.0))).astype(int), 0, len(v.pyr) - 1)
    axes = np.column_stack((np.cos(f.angle), np.sin(f.angle)))
    levels = np.unique(lev)
    out = None if len(levels) == 1 else np.empty((len(f), PATCH * PATCH * C), np.float32)
    for k in levels:
        idx = np.flatnonzero(lev == k)
        s = 2.0 ** -k
        off = t[None] * (f.span_px[idx] * s)[:, None]
        p, cut = sample_frames_raw(v.pyr[k], (f.xy[idx] + 0.5) * s - 0.5, axes[idx], off, off)
        if p.dtype != np.uint8:
            np.nan_to_num(p, copy=False)     # a neighbourhood cut by the frame: its missing part counts as 0
        p = p.astype(np.float32, copy=False)
        if cut is not None:                  # (uint8 samples: the mask says where)
            p[cut] = 0.0
        p = p.reshape(len(idx), -1)
        if out is None:                      # one level (the usual case): no copy
            out = p
        else:
            out[idx] = p
    if out is None:
        return np.zeros((0, PATCH * PATCH * C), np.float32)
    out -= out.mean(axis=1, keepdims=True)
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-6)
    return out


def undistorted(calib: StereoCalibration, pts: np.ndarray, cam: int) -> np.ndarray:
    if not calib.has_distortion:
        return np.asarray(pts, float).reshape(-1, 2)
    return undistort_pixels(pts, calib.K1 if cam == 1 else calib.K2, calib.D1 if cam == 1 else calib.D2)


def match_forks(calib: StereoCalibration, left: View, right: View, band_px: float = 3.0,
                min_ncc: float = 0.4, max_angle_deg: float = 45.0, max_span_ratio: float = 1.6) -> ForkPairs:
    """One-to-one pairs of left and right forks (epipolar pairing of detections, NCC evidence)."""
    n1, n2 = len(left.fins), len(right.fins)
    empty = ForkPairs(np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0))
    if n1 == 0 or n2 == 0:
        return empty
    F = fundamental_from_projections(calib.P1, calib.P2)
    p1, p2 = undistorted(calib, left.fins.xy, 1), undistorted(calib, right.fins.xy, 2)
    lines = epipolar_lines(F, p1)
    dist = np.abs(lines[:, :2] @ p2.T + lines[:, 2:])                               # (n1, n2)
    # a fork is located to ~1 % of the fish's length in each image: the band grows with the fin
    band = band_px + 0.07 * np.minimum(left.fins.span_px[:, None], right.fins.span_px[None])
    dang = np.abs(np.angle(np.exp(1j * (left.fins.angle[:, None] - right.fins.angle[None]))))
    ratio = left.fins.span_px[:, None] / right.fins.span_px[None]
    ncc = _patches(left) @ _patches(right).T
    ok = ((dist <= band) & (dang <= np.radians(max_angle_deg)) & (ncc >= min_ncc)
          & (ratio <= max_span_ratio) & (ratio >= 1 / max_span_ratio))
    score = np.where(ok, ncc - 0.1 * dist / band, -np.inf)
    pi, pj = [], []
    for _ in range(min(n1, n2)):                     # greedy, best first; a few dozen forks
        k = int(score.argmax())
        a, b = divmod(k, n2)
        if not np.isfinite(score[a, b]):
            break
        pi.append(a)
        pj.append(b)
        score[a, :] = -np.inf
        score[:, b] = -np.inf
    if not pi:
        return empty
    i, j = np.array(pi), np.array(pj)
    return ForkPairs(i, j, ncc[i, j], dist[i, j])


def snout_search_range(calib: StereoCalibration, fork_mm: np.ndarray, span_px: np.ndarray,
                       min_len_mm: float, max_len_mm: float, span_of_fl: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel distances from the fork (N,) between which a snout can lie in image 1: the species'
    lengths at the fork's depth (foreshortened down to 40 %), and no farther than 3x the length the
    fin's span suggests."""
    f, _ = camera_frame(calib.P1)
    P = normalise_projection(calib.P1)
    depth = np.column_stack((fork_mm, np.ones(len(fork_mm)))) @ P[2]
    depth = np.maximum(depth, 1e-6)
    lo = 0.4 * min_len_mm * f / depth
    hi = np.minimum(1.15 * max_len_mm * f / depth, 3.0 * span_px / span_of_fl)
    return lo, np.maximum(hi, lo + 4.0)


def tilt_deg(axis_mm: np.ndarray, up: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(axis_mm, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.degrees(np.arcsin(np.clip(np.abs(axis_mm @ up) / n, 0, 1)))


@dataclass
class SnoutChoice:
    """Per matched fork pair (N,): the chosen snout in both images and in 3-D."""

    px1: np.ndarray         # (N, 2)
    px2: np.ndarray         # (N, 2)
    mm: np.ndarray          # (N, 3)
    residual_px: np.ndarray
    length_mm: np.ndarray
    tilt_deg: np.ndarray
    strength: np.ndarray    # min of the two images' snout strengths
    ok: np.ndarray          # (N,) bool


def pair_snouts(calib: StereoCalibration, fork_mm: np.ndarray, px1: np.ndarray, s1: np.ndarray,
                px2: np.ndarray, s2: np.ndarray, min_len_mm: float, max_len_mm: float, max_tilt: float,
                up: np.ndarray, max_residual_px: float | np.ndarray = 2.5,
                expected_mm: np.ndarray | None = None, ncc: np.ndarray | None = None,
                min_ncc: float = 0.3) -> SnoutChoice:
    """The best combination of snout candidates (N, K, 2) / strengths (N, K) of both images per fish:
    strongest in both, within the epipolar residual, the species' length and tilt, and nearest the
    length the fin's size suggests (``expected_mm``, (N,), +-30 %). A fish swims along the rig's
    baseline more often than not, so its axis lies along the epipolar lines and the residual cannot
    tell one snout candidate on it from another: the two views' patches (``ncc`` (N, K, K), zero-mean
    NCC), strength and size decide, the residual only gates."""
    N, K = s1.shape[:2]
    a = np.broadcast_to(px1[:, :, None], (N, K, K, 2)).reshape(-1, 2)
    b = np.broadcast_to(px2[:, None, :], (N, K, K, 2)).reshape(-1, 2)
    has = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    X = np.full((len(a), 3), np.nan)
    res = np.full(len(a), np.inf)
    if has.any():
        X[has], res[has] = triangulate_calibrated(calib, np.nan_to_num(a[has]), np.nan_to_num(b[has]))
    X, res = X.reshape(N, K, K, 3), res.reshape(N, K, K)
    axis = X - fork_mm[:, None, None]
    length = np.linalg.norm(axis, axis=-1)
    tilt = tilt_deg(axis, up)
    strength = np.minimum(s1[:, :, None], s2[:, None, :])
    gate = np.broadcast_to(np.asarray(max_residual_px, float), (N,))[:, None, None]
    good = (has.reshape(N, K, K) & (res <= gate) & (length >= min_len_mm)
            & (length <= max_len_mm) & (tilt <= max_tilt))
    prior = 1.0
    if expected_mm is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            prior = np.exp(-(np.log(length / expected_mm[:, None, None]) / 0.3) ** 2)
    alike = 1.0 if ncc is None else np.clip(ncc, 0.0, 1.0) ** 2
    if ncc is not None:
        good &= ncc >= min_ncc
    merit = np.where(good, s1[:, :, None] * s2[:, None, :] * prior * alike, -1.0).reshape(N, -1)
    best = merit.argmax(axis=1)
    bi, bj = np.divmod(best, K)
    rows = np.arange(N)
    pick = (rows, bi, bj)
    return SnoutChoice(px1[rows, bi], px2[rows, bj], X[pick], res[pick], length[pick], tilt[pick],
                       strength[pick], merit[rows, best] >= 0)


def patch_ncc(pyr1: list[np.ndarray], pyr2: list[np.ndarray], pts1: np.ndarray, pts2: np.ndarray,
              angle1: np.ndarray, angle2: np.ndarray, size_px: np.ndarray, n: int = 11) -> np.ndarray:
    """Zero-mean NCC (N, K, K) between every left and right point (N, K, 2) of a fish, each patch
    sampled in its own image's fish frame (``angle``, (N,)), ``size_px`` (N,) wide: the same
    structure seen by both cameras correlates, two points along the same epipolar line do not."""
    N, K = pts1.shape[:2]
    t = np.linspace(-0.5, 0.5, n)[None] * np.repeat(np.asarray(size_px, float), K)[:, None]
    vecs = []
    for pyr, pts, ang in ((pyr1, pts1, angle1), (pyr2, pts2, angle2)):
        flat = np.nan_to_num(pts.reshape(-1, 2), nan=-1e4)
        a = np.repeat(ang, K)
        axes = np.column_stack((np.cos(a), np.sin(a)))
        step = np.repeat(np.asarray(size_px, float), K) / n
        lev = np.clip(np.floor(np.log2(np.maximum(step, 1.0))).astype(int), 0, len(pyr) - 1)
        C = pyr[0].shape[2] if pyr[0].ndim == 3 else 1
        v = np.full((len(flat), n * n * C), np.nan, np.float32)
        for k in np.unique(lev):
            idx = np.flatnonzero(lev == k)
            f = 2.0 ** -k
            w = sample_frames(pyr[k], (flat[idx] + 0.5) * f - 0.5, axes[idx], t[idx] * f, t[idx] * f)
            v[idx] = w.reshape(len(idx), -1)
        bad = np.isnan(v).any(axis=1)
        v[bad] = 0.0
        v = v - v.mean(axis=1, keepdims=True)
        v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-6)
        v[bad] = 0.0
        vecs.append(v.reshape(N, K, -1))
    return np.einsum("nkc,nlc->nkl", vecs[0], vecs[1])


def transfer_forks(P_src: np.ndarray, P_dst: np.ndarray, src: View, dst: View, idx: np.ndarray,
                   near_mm: float, far_mm: float, steps: int = 96) -> Fins:
    """Where forks ``idx`` of one image should be in the other: along each one's epipolar line
    (between ``near_mm`` and ``far_mm`` from the source camera), the position whose neighbourhood,
    sampled in the fork's frame, correlates best with the fork's own. A fin seen faintly in one
    view is then located where the other view says it is instead of being looked for blind.
    Returns hypotheses (angle and span from the source) for ``vision.fork.locate_forks``."""
    f = src.fins.take(idx)
    n = len(f)
    if n == 0:
        return Fins.empty()
    seg = segments_by_range(P_src, P_dst, f.xy, near_mm, far_mm)                 # (n, 2, 2)
    u = np.linspace(0.0, 1.0, steps)
    pts = seg[:, :1] + u[None, :, None] * (seg[:, 1:] - seg[:, :1])              # (n, steps, 2)
    h, w = dst.pyr[0].shape[:2]
    cand = Fins(pts.reshape(-1, 2), np.repeat(f.angle, steps), np.repeat(f.span_px, steps),
                np.ones(n * steps), np.ones(n * steps))
    ncc = np.matmul(_patches(dst, cand).reshape(n, steps, -1), _patches(src, f)[:, :, None])[..., 0]
    inside = np.all((pts >= 0) & (pts <= [w - 1, h - 1]), axis=2)
    best = np.where(inside, ncc, -np.inf).argmax(axis=1)
    return Fins(pts[np.arange(n), best], f.angle.copy(), f.span_px.copy(), ncc[np.arange(n), best], f.polarity.copy(),
                None if f.body is None else f.body.copy())


def transfer_snouts(P1: np.ndarray, P2: np.ndarray, left: View, right: View, px1: np.ndarray,
                    angle1: np.ndarray, angle2: np.ndarray, size_px: np.ndarray, near_mm: np.ndarray,
                    far_mm: np.ndarray, steps: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Where each left snout candidate (N, K, 2) is in the right image: along its epipolar line,
    between ``near_mm`` and ``far_mm`` (N,) from camera 1, the position whose neighbourhood
    (``size_px`` (N,) wide, in each image's fish frame) correlates best with the left one's.
    Returns positions (N, K, 2) (NaN where the left has none) and their NCC (N, K)."""
    N, K = px1.shape[:2]
    out = np.full((N, K, 2), np.nan)
    score = np.zeros((N, K))
    has = np.all(np.isfinite(px1), axis=2)
    if not has.any():
        return out, score
    n_idx, k_idx = np.nonzero(has)
    pts = px1[n_idx, k_idx]
    seg = segments_by_range(P1, P2, pts, near_mm[n_idx], far_mm[n_idx])
    u = np.linspace(0.0, 1.0, steps)
    cand = seg[:, :1] + u[None, :, None] * (seg[:, 1:] - seg[:, :1])                # (M, steps, 2)
    M = len(pts)
    src = Fins(pts, angle1[n_idx], size_px[n_idx], np.ones(M), np.ones(M))
    dst = Fins(cand.reshape(-1, 2), np.repeat(angle2[n_idx], steps), np.repeat(size_px[n_idx], steps),
               np.ones(M * steps), np.ones(M * steps))
    ncc = np.matmul(_patches(right, dst).reshape(M, steps, -1), _patches(left, src)[:, :, None])[..., 0]
    h, w = right.pyr[0].shape[:2]
    inside = np.all((cand >= 0) & (cand <= [w - 1, h - 1]), axis=2)
    best = np.where(inside, ncc, -np.inf).argmax(axis=1)
    out[n_idx, k_idx] = cand[np.arange(M), best]
    score[n_idx, k_idx] = np.maximum(ncc[np.arange(M), best], 0.0)
    return out, score
