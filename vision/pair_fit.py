"""How well a stereo pair fits its calibration, from the pair's own texture: a survey that found no
fish at all says why when the cause is the calibration or the order of the views, not the water.

ORB features matched across the views (mutual best, Lowe's ratio, then the inliers of the pair's
own fundamental matrix by RANSAC), undistorted with the calibration's lens model, then, as given
and with the views swapped:
- ``epipolar_px``: the median distance of a match to its epipolar line (symmetric, in pixels):
  a calibration made for other cameras, or another placing of them, misses by tens of pixels;
- ``in_front``: the share of matches that triangulate in front of both cameras with a residual
  under ``RESIDUAL_PX``: views swapped against a convergent or parallel rig put the points behind.
  Judged only where the world is camera 1's frame (P1 = K1 [I | 0]: OpenCV's, the chessboard's,
  an import's): P is known only up to sign, and a DLT world may be mirrored, where "in front" by
  det(P) is behind; elsewhere NaN, and the epipolar misses alone speak (a parallel rig's swap
  leaves them as they were: said nothing).

Pure: two images and a ``StereoCalibration`` in, figures out. A pair without texture (a blank or
saturated frame) gives fewer than ``MIN_MATCHES`` matches and no verdict.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vision.calib_file import StereoCalibration
from vision.epipolar import fundamental_from_projections
from vision.survey_types import plain_image
from vision.triangulation import normalise_projection, triangulate, undistort_pixels

MIN_MATCHES = 30
RESIDUAL_PX = 3.0
RATIO = 0.8
RANSAC_PX = 1.5
GOOD_PX = 3.0          # a rig's own calibration: its matches ~0.5-1 px off their lines
GOOD_FRONT = 0.7


@dataclass(frozen=True)
class Fit:
    matches: int
    epipolar_px: float          # median symmetric epipolar distance, views as given
    in_front: float             # share in front of both cameras with a small residual, as given
    epipolar_swapped_px: float
    in_front_swapped: float

    @property
    def judged(self) -> bool:
        return self.matches >= MIN_MATCHES


def _grey8(img: np.ndarray) -> np.ndarray:
    img = plain_image(img)
    if img.dtype != np.uint8:
        img = cv2.normalize(img.astype(np.float32), None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def _matches(left: np.ndarray, right: np.ndarray, features: int) -> tuple[np.ndarray, np.ndarray]:
    orb = cv2.ORB_create(nfeatures=features)
    k1, d1 = orb.detectAndCompute(_grey8(left), None)
    k2, d2 = orb.detectAndCompute(_grey8(right), None)
    if d1 is None or d2 is None or len(k1) < 2 or len(k2) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    forward = bf.knnMatch(d1, d2, k=2)
    backward = {m.queryIdx: m.trainIdx for m in bf.match(d2, d1)}
    keep = [pair[0] for pair in forward if len(pair) == 2 and pair[0].distance < RATIO * pair[1].distance
            and backward.get(pair[0].trainIdx) == pair[0].queryIdx]
    p1 = np.array([k1[m.queryIdx].pt for m in keep], float).reshape(-1, 2)
    p2 = np.array([k2[m.trainIdx].pt for m in keep], float).reshape(-1, 2)
    return p1, p2


def _consistent(p1: np.ndarray, p2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The matches of the pairs' own epipolar geometry, whatever the calibration says (RANSAC): true
    matches (water, noise and repeated texture give ORB many that are not)."""
    if len(p1) < MIN_MATCHES:
        return p1, p2
    _, inliers = cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, RANSAC_PX, 0.999)
    if inliers is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    inliers = inliers.ravel().astype(bool)
    return p1[inliers], p2[inliers]


def _camera1_world(P1: np.ndarray) -> bool:
    P1 = np.asarray(P1, float)
    if P1[2, 2] == 0:
        return False
    M = P1[:, :3] / P1[2, 2]
    return bool(np.abs(P1[:, 3]).max() <= 1e-9 * np.abs(P1).max() and np.allclose(M, np.triu(M), atol=1e-9)
                and M[0, 0] > 0 and M[1, 1] > 0)


def _judge(P1: np.ndarray, P2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> tuple[float, float]:
    F = fundamental_from_projections(P1, P2)
    h1, h2 = np.c_[x1, np.ones(len(x1))], np.c_[x2, np.ones(len(x2))]
    l2, l1 = h1 @ F.T, h2 @ F
    d2 = np.abs(np.sum(l2 * h2, axis=1)) / np.maximum(np.hypot(l2[:, 0], l2[:, 1]), 1e-12)
    d1 = np.abs(np.sum(l1 * h1, axis=1)) / np.maximum(np.hypot(l1[:, 0], l1[:, 1]), 1e-12)
    X, residual = triangulate(P1, P2, x1, x2)
    Xh = np.c_[X, np.ones(len(X))]
    depth1 = Xh @ normalise_projection(P1)[2]
    depth2 = Xh @ normalise_projection(P2)[2]
    front = (depth1 > 0) & (depth2 > 0) & (residual < RESIDUAL_PX)
    return float(np.median(np.maximum(d1, d2))), float(front.mean())


def pair_fit(pairs: list[tuple[np.ndarray, np.ndarray]], calib: StereoCalibration, features: int = 3000) -> Fit:
    """``Fit`` of a rig's pairs (each view (H, W) or (H, W, 3), 8 or 16 bits) to ``calib``: their
    matches pooled (one rig, one epipolar geometry, whatever swims in front of it)."""
    found = [_matches(left, right, features) for left, right in pairs]
    p1 = np.concatenate([f[0] for f in found]) if found else np.zeros((0, 2))
    p2 = np.concatenate([f[1] for f in found]) if found else np.zeros((0, 2))
    p1, p2 = _consistent(p1, p2)
    if calib.has_distortion and len(p1):
        u1, u2 = undistort_pixels(p1, calib.K1, calib.D1), undistort_pixels(p2, calib.K2, calib.D2)
        s1, s2 = undistort_pixels(p2, calib.K1, calib.D1), undistort_pixels(p1, calib.K2, calib.D2)
    else:
        u1, u2, s1, s2 = p1, p2, p2, p1
    ok = np.isfinite(np.c_[u1, u2, s1, s2]).all(axis=1)
    n = int(ok.sum())
    nan = float("nan")
    if n < MIN_MATCHES:
        return Fit(n, nan, nan, nan, nan)
    given = _judge(calib.P1, calib.P2, u1[ok], u2[ok])
    swapped = _judge(calib.P1, calib.P2, s1[ok], s2[ok])
    depth = _camera1_world(calib.P1)
    return Fit(n, given[0], given[1] if depth else nan, swapped[0], swapped[1] if depth else nan)


def verdict(fit: Fit, epipolar_limit_px: float = 8.0) -> str | None:
    """What is wrong with the pair against its calibration, in a user's words, or None."""
    if not fit.judged:
        return None
    depth = not np.isnan(fit.in_front)
    front = (f"; {fit.in_front:.0%} of them triangulate in front of both cameras as given, "
             f"{fit.in_front_swapped:.0%} exchanged") if depth else ""
    good = fit.epipolar_px <= GOOD_PX and (not depth or fit.in_front >= GOOD_FRONT)
    swapped_good = fit.epipolar_swapped_px <= GOOD_PX and (not depth or fit.in_front_swapped >= GOOD_FRONT)
    if good:
        return None
    if swapped_good:
        return (f"left and right look swapped against the calibration: {fit.matches} matched features miss "
                f"their epipolar lines by {fit.epipolar_px:.1f} px as given, {fit.epipolar_swapped_px:.1f} px with "
                f"the views exchanged{front}")
    if fit.epipolar_px > epipolar_limit_px or (depth and fit.in_front < 0.5):
        return (f"the pairs do not fit the calibration: {fit.matches} matched features miss their epipolar "
                f"lines by {fit.epipolar_px:.1f} px (median){front}: a calibration of other cameras, "
                f"or cameras moved since it was made")
    return None
