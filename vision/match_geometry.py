"""Where stereo matching looks: epipolar frames, search segments, and bilinear sampling in them.

Each window is sampled (bilinear, cv2.remap) in a frame turned to its own epipolar line, which is
stereo rectification done locally. Pixels follow OpenCV's convention.
"""
from __future__ import annotations

import cv2
import numpy as np

from vision.epipolar import epipolar_lines
from vision.triangulation import camera_centre

_REMAP_ROWS = 32_000           # cv2.remap refuses maps of SHRT_MAX rows or more


def _unit_dirs(lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (N, 2) of lines (N, 3) and normals (the directions turned +90 degrees)."""
    d = np.column_stack((lines[:, 1], -lines[:, 0]))
    d /= np.hypot(d[:, 0], d[:, 1])[:, None]
    return d, np.column_stack((-d[:, 1], d[:, 0]))


def line_frames(F: np.ndarray, pts1: np.ndarray):
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
    d1, n1 = _unit_dirs(np.column_stack((origin, np.ones(len(origin)))) @ F)        # l1 = F^T x2, x2 on l2
    flip = np.einsum("nd,nd->n", d1, d2) < 0
    d1[flip] *= -1
    n1[flip] *= -1
    return lines, d2, n2, origin, d1, n1


def segments_by_offset(pts1: np.ndarray, F: np.ndarray, lo_px: float, hi_px: float) -> np.ndarray:
    """Search segments (N, 2, 2) on the epipolar lines of pts1 (N, 2): from ``lo_px`` to ``hi_px``
    along the line from the foot of pts1's own coordinates, positive towards +u (+v if vertical).
    For cameras side by side (camera 2 on the right), the offset is minus the disparity u1 - u2."""
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    _, d, _, origin, _, _ = line_frames(F, pts1)
    return np.stack([origin + lo_px * d, origin + hi_px * d], axis=1)


def segments_by_range(P1: np.ndarray, P2: np.ndarray, pts1: np.ndarray, near_mm: float | np.ndarray,
                      far_mm: float | np.ndarray) -> np.ndarray:
    """Search segments (N, 2, 2) in image 2: images of the points of pts1's lines of sight between
    ``near_mm`` and ``far_mm`` (scalars or (N,)) from camera 1's centre: a rig's working distance.
    P1 must give positive depths in front of camera 1, as both calibrators write it."""
    P1 = np.asarray(P1, dtype=float)
    P2 = np.asarray(P2, dtype=float)
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    centre = camera_centre(P1)
    rays = np.linalg.solve(P1[:, :3], np.column_stack((pts1, np.ones(len(pts1)))).T).T
    # X = C + lam * ray images to lam * (u, v, 1): lam is its depth up to P1's positive scale, so
    # lam > 0 is in front of camera 1 in a left-handed world frame as much as in a right-handed one
    rays /= np.linalg.norm(rays, axis=1)[:, None]
    ends = []
    for dist in (near_mm, far_mm):
        dist = np.broadcast_to(np.asarray(dist, dtype=float), (len(pts1),))[:, None]
        x = (centre + dist * rays) @ P2[:, :3].T + P2[:, 3]
        ends.append(x[:, :2] / x[:, 2:])
    return np.stack(ends, axis=1)


def inside_span(origin, d, n, shape, along, across):
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


def sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of img at float positions (x, y) of any shape (leading axes kept)."""
    shape = x.shape
    cols = shape[-1]
    for size in shape[-2::-1]:          # fold trailing axes into long map rows: few rows, little overhead
        if cols * size >= _REMAP_ROWS:
            break
        cols *= size
    x, y = (v.reshape(-1, cols).astype(np.float32, copy=False) for v in (x, y))
    out = [cv2.remap(img, x[r:r + _REMAP_ROWS], y[r:r + _REMAP_ROWS], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE) for r in range(0, len(x), _REMAP_ROWS)]
    return (out[0] if len(out) == 1 else np.concatenate(out)).reshape(shape)


def frame_grid(base, d, n, rows, cols) -> tuple[np.ndarray, np.ndarray]:
    """Positions x, y (..., R, C) of base + cols d + rows n: rows (R,) across the line, cols (C,)
    along it; base, d, n (..., 2) broadcast together. One float32 broadcast add per axis, the
    long axis innermost (an interleaved (x, y) axis would make numpy loop over pairs)."""
    f32 = np.float32
    rows, cols = np.asarray(rows, f32)[:, None], np.asarray(cols, f32)
    base, d, n = (np.asarray(v, f32)[..., None, None, :] for v in (base, d, n))
    return tuple((base[..., i] + rows * n[..., i]) + cols * d[..., i] for i in (0, 1))


def windows(img: np.ndarray, centres, d, n, h: int) -> np.ndarray:
    """Windows (..., p, p) of img, rows along n and columns along d, centred on centres (..., 2);
    d and n broadcast against centres."""
    a = np.arange(-h, h + 1)
    return sample(img, *frame_grid(centres, d, n, a, a))
