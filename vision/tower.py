"""The tower camera's homography: pixel (u, v, 1) -> pond plane (x_m, y_m, 1), from surveyed points.

``fit_tower(px, pond_m)`` fits H with OpenCV's ``findHomography`` (method 0: least squares on all
points, normalised as OpenCV does, then refined on the error) and returns it with each point's
error in metres on the pond. Sets that cannot fix a homography are refused by name
(``TowerInputError``): fewer than 4 points, non-finite values, duplicate points, all points on one
line in the image or on the pond, three of only four on one line, too few points off a line (the
linear system's null space is not one-dimensional), and a singular or non-finite H.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

MIN_POINTS = 4
LINE_TOL = 1e-3        # thinness (normalised) under which points count as on one line
NULL_TOL = 1e-7        # second-smallest / largest singular value of the normalised DLT system
DET_TOL = 1e-12        # |det H| / |H|^3 under which H counts as singular


class TowerInputError(ValueError):
    """A reference-point set that cannot give a homography; the message says why."""


@dataclass(frozen=True)
class TowerFit:
    H: np.ndarray               # 3x3, pixel -> pond (m), H[2, 2] == 1
    residuals_m: np.ndarray     # (N,) distance on the pond between each point and its mapped pixel

    @property
    def rms_m(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residuals_m))))

    @property
    def max_m(self) -> float:
        return float(np.max(self.residuals_m))


def to_pond(H: np.ndarray, px: np.ndarray) -> np.ndarray:
    """(N, 2) pond positions (m) of (N, 2) pixels; points on the horizon come out non-finite."""
    px = np.asarray(px, dtype=float).reshape(-1, 2)
    h = np.c_[px, np.ones(len(px))] @ np.asarray(H, dtype=float).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return h[:, :2] / h[:, 2:3]


def seen_from_above(H: np.ndarray, px: np.ndarray) -> bool:
    """Whether H maps the pixels ``px`` (N, 2) onto the pond as a camera above it sees it: the
    image's (u right, v down) turns the other way round from the pond's (x, y) with z up, so the
    map's Jacobian is negative there (det H / w^3, w = H[2] . (u, v, 1)). Positive: the pond seen
    mirrored — an axis of the survey measured the other way, or a camera that mirrors its image."""
    H = np.asarray(H, dtype=float)
    centre = np.asarray(px, dtype=float).reshape(-1, 2).mean(axis=0)
    w = float(H[2] @ np.r_[centre, 1.0])
    return float(np.sign(np.linalg.det(H)) * np.sign(w)) < 0


def _normalise(p: np.ndarray) -> np.ndarray:
    """Hartley: centroid at 0, mean distance sqrt(2) (the scale findHomography uses)."""
    c = p - p.mean(axis=0)
    scale = np.mean(np.linalg.norm(c, axis=1))
    return c * (np.sqrt(2.0) / scale) if scale > 0 else c


def _thinness(p: np.ndarray) -> float:
    """Smallest / largest spread of a point set (0: all on one line)."""
    s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0


def _check_set(p: np.ndarray, where: str) -> None:
    n = len(p)
    scale = float(np.max(np.ptp(p, axis=0))) or 1.0
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
    i, j = np.nonzero(np.triu(d <= 1e-9 * scale, k=1))
    if len(i):
        raise TowerInputError(f"points {i[0] + 1} and {j[0] + 1} are the same {where}")
    q = _normalise(p)
    if _thinness(q) < LINE_TOL:
        raise TowerInputError(f"all {n} points lie on one line {where}")
    if n == MIN_POINTS:
        for tri in combinations(range(n), 3):
            a, b, c = q[list(tri)]
            area2 = abs((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
            longest = max(np.linalg.norm(b - a), np.linalg.norm(c - a), np.linalg.norm(c - b))
            if area2 < LINE_TOL * longest ** 2:
                names = ", ".join(str(k + 1) for k in tri)
                raise TowerInputError(f"points {names} lie on one line {where}: "
                                      "with only 4 points, no three may be in line")


def _check_system(px: np.ndarray, pond: np.ndarray) -> None:
    """The normalised DLT system must have a one-dimensional null space (else H is not fixed)."""
    a, b = _normalise(px), _normalise(pond)
    rows = []
    for (u, v), (x, y) in zip(a, b, strict=True):
        rows.append([u, v, 1, 0, 0, 0, -x * u, -x * v, -x])
        rows.append([0, 0, 0, u, v, 1, -y * u, -y * v, -y])
    rows += [[0.0] * 9] * max(0, 9 - len(rows))       # 4 points: 8 equations, 9 singular values
    s = np.linalg.svd(np.asarray(rows), compute_uv=False)
    if s[-2] < NULL_TOL * s[0]:
        raise TowerInputError("the points do not fix a homography (all but one on one line?)")


def fit_tower(px: np.ndarray, pond_m: np.ndarray) -> TowerFit:
    """Homography pixel -> pond from N >= 4 matched points; TowerInputError when it cannot."""
    import cv2

    px = np.asarray(px, dtype=float)
    pond = np.asarray(pond_m, dtype=float)
    if px.ndim != 2 or px.shape[1:] != (2,) or pond.shape != px.shape:
        raise TowerInputError(f"expected two (N, 2) arrays of equal length, got {px.shape} and {pond.shape}")
    if len(px) < MIN_POINTS:
        raise TowerInputError(f"{len(px)} points: at least {MIN_POINTS} are needed")
    if not (np.all(np.isfinite(px)) and np.all(np.isfinite(pond))):
        raise TowerInputError("a value is not a finite number")
    _check_set(px, "in the image")
    _check_set(pond, "on the pond")
    _check_system(px, pond)
    H, _ = cv2.findHomography(px, pond, 0)
    if H is None or not np.all(np.isfinite(H)) or H[2, 2] == 0:
        raise TowerInputError("OpenCV found no finite homography for these points")
    H = H / H[2, 2]
    if abs(np.linalg.det(H)) < DET_TOL * np.linalg.norm(H) ** 3:
        raise TowerInputError("the homography is singular")
    w = np.c_[px, np.ones(len(px))] @ H[2]
    if not (np.all(w > 0) or np.all(w < 0)):
        # w is affine in the pixel: one sign at every point is one sign over their hull. Opposite
        # signs put the homography's horizon among the points: the pond seen folded over, which no
        # camera sees (two points' pond positions swapped?). Fit exactly, it passed as RMS 0
        side = 1.0 if np.sum(w > 0) >= np.sum(w < 0) else -1.0       # the side most points lie on
        odd = int(np.flatnonzero(side * w <= 0)[0])
        raise TowerInputError(f"no camera sees the pond so: the fit's horizon runs among the points (point "
                              f"{odd + 1} lies beyond it); are two points' pond positions swapped?")
    residuals = np.linalg.norm(to_pond(H, px) - pond, axis=1)
    if not np.all(np.isfinite(residuals)):
        raise TowerInputError("a reference pixel maps to infinity (on the horizon)")
    return TowerFit(H=H, residuals_m=residuals)
