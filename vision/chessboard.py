"""Stereo calibration from pairs of views of a printed chessboard, with OpenCV.

Procedure (``calibrate_pairs``):
1. corners: ``find_corners`` (findChessboardCorners, retried on a 2x enlargement like OpenCV's
   stereo_calib sample), refined by cornerSubPix in a window sized from the board's own square size
   in that image: a fixed 11x11 window reaches across neighbouring corners when squares are small
   (on OpenCV's sample pair 02 it doubles the reprojection error);
2. each camera alone (calibrateCamera, k1 k2 p1 p2 distortion), then both together
   (stereoCalibrate refining everything from there);
3. pairs that are not two views of one moment are rejected before the stereo fit: each camera's own
   fit places the board in its view, so each pair gives the rig (camera 2 from camera 1); a pair
   whose rig is more than ``POSE_TOL_DEG`` or ``POSE_TOL_SHARE`` of the baseline off the rig most
   pairs agree on is left out (real pairs agree within 0.44 deg and 3 % on the shared set; a pair
   mixed up with another moment's view was 83 deg off there). A joint fit spreads two such pairs'
   error over every pair (5-26 px each), so the RMS test below missed them and wrote a 300 mm
   baseline for a 120 mm rig, at exit 0;
4. pairs whose reprojection RMS exceeds ``outlier_factor`` x the median (and ``outlier_floor_px``)
   are rejected and the calibration is run again without them. A fit still over ``MAX_RMS_PX`` is
   no calibration (``BadFit``).

World frame: camera 1, millimetres (board points are scaled by the square size), so
P1 = K1 [I | 0] and P2 = K2 [R | T]. Corners are (n, 2) arrays in the board's row-major order
(``pattern`` = (columns, rows) of inner corners, OpenCV's order).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from vision.calib_file import StereoCalibration
from vision.epipolar import fundamental_from_projections
from vision.triangulation import undistort_pixels

_SUBPIX = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
_SOLVE = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-7)
_DISTORTION = cv2.CALIB_FIX_K3          # k1 k2 p1 p2: k3 overfits with a dozen views of one board
POSE_TOL_DEG = 2.0
POSE_TOL_SHARE = 0.1
MAX_RMS_PX = 3.0        # sub-pixel corners fit to ~0.2-1 px; 3 px is views that do not belong together


class BadFit(ValueError):
    """The pairs fit no rig: views of different moments, or of different boards."""


class NotEnoughPairs(ValueError):
    """Fewer usable pairs than a stereo calibration needs; ``pairs`` says what happened to each."""

    def __init__(self, message: str, pairs: list[PairReport]):
        super().__init__(message)
        self.pairs = pairs


@dataclass
class PairReport:
    index: int                  # position of the pair in the input order
    used: bool
    reason: str                 # "used", "board not found in left|right|both", "outlier: ..."
    rms_px: float | None = None  # reprojection RMS of this pair (both images)


@dataclass
class ChessboardResult:
    calibration: StereoCalibration
    rms_px: float               # stereoCalibrate's RMS reprojection error over the used pairs
    epipolar_px: float          # ``epipolar_error`` over the used pairs
    pairs: list[PairReport]
    square_mm: float
    corners1: list[np.ndarray] = field(default_factory=list)    # used pairs only, (n, 2) each
    corners2: list[np.ndarray] = field(default_factory=list)

    @property
    def baseline_squares(self) -> float:
        return float(np.linalg.norm(self.calibration.T) / self.square_mm)


def board_points(pattern: tuple[int, int], square: float) -> np.ndarray:
    """Inner corners (cols*rows, 3) float32 on the z = 0 plane, row-major like OpenCV finds them."""
    cols, rows = pattern
    grid = np.zeros((rows * cols, 3), np.float32)
    grid[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square
    return grid


def _spacing(corners: np.ndarray, pattern: tuple[int, int]) -> float:
    grid = corners.reshape(pattern[1], pattern[0], 2)
    return float(min(np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
                     np.linalg.norm(np.diff(grid, axis=1), axis=2).min()))


def find_corners(img: np.ndarray, pattern: tuple[int, int], *, fast_check: bool = True,
                 subpix_half: int | None = None) -> np.ndarray | None:
    """Sub-pixel inner corners (n, 2) float32 of a grey image (H, W), or None if not found.

    ``fast_check`` gives up on a view without any board in ~0.05 s instead of ~0.5 s.
    ``subpix_half``: cornerSubPix's half window; None sizes it from the board (see module docstring).
    """
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    if fast_check:
        flags |= cv2.CALIB_CB_FAST_CHECK
    for scale in (1, 2):     # small boards are sometimes only found on an enlarged image
        big = img if scale == 1 else cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
        found, corners = cv2.findChessboardCorners(big, pattern, flags=flags)
        if found:
            corners = corners.reshape(-1, 2) / scale
            break
    else:
        return None
    # half window ~ 0.3 of the smallest corner spacing, 3..11 px: inside one square's neighbourhood
    half = int(np.clip(0.3 * _spacing(corners, pattern), 3, 11)) if subpix_half is None else subpix_half
    refined = cv2.cornerSubPix(img, corners.reshape(-1, 1, 2).astype(np.float32), (half, half), (-1, -1),
                               _SUBPIX)
    return refined.reshape(-1, 2)


def consistent_order(corners1: np.ndarray, corners2: np.ndarray) -> np.ndarray:
    """corners2, reversed if the detector numbered the board from the opposite corner in image 2
    (the 180-degree ambiguity): the first-to-last corner direction must agree between the views."""
    way1, way2 = corners1[-1] - corners1[0], corners2[-1] - corners2[0]
    return corners2[::-1].copy() if float(way1 @ way2) < 0 else corners2


def epipolar_error(corners1, corners2, K1, D1, K2, D2, F) -> float:
    """Mean epipolar error as OpenCV's stereo_calib sample computes it: corners undistorted with
    (K, D, P=K), then per corner |distance to its line from the other image| in image 2 plus the
    same in image 1, averaged over all corners. Lists of (n, 2) arrays, one per pair."""
    x1 = undistort_pixels(np.concatenate(corners1), K1, D1)
    x2 = undistort_pixels(np.concatenate(corners2), K2, D2)
    h1, h2 = np.c_[x1, np.ones(len(x1))], np.c_[x2, np.ones(len(x2))]
    l2, l1 = h1 @ F.T, h2 @ F              # line of x1 in image 2, of x2 in image 1
    d2 = np.abs(np.einsum("ij,ij->i", h2, l2)) / np.hypot(l2[:, 0], l2[:, 1])
    d1 = np.abs(np.einsum("ij,ij->i", h1, l1)) / np.hypot(l1[:, 0], l1[:, 1])
    return float(np.mean(d1 + d2))


def square_sizes(calib: StereoCalibration, corners1: np.ndarray, corners2: np.ndarray,
                 pattern: tuple[int, int]) -> np.ndarray:
    """3-D distances (mm) between neighbouring corners of one pair's board, triangulated with
    P1/P2 after undistortion: all horizontal then all vertical neighbours."""
    x1 = undistort_pixels(corners1, calib.K1, calib.D1)
    x2 = undistort_pixels(corners2, calib.K2, calib.D2)
    X = cv2.triangulatePoints(calib.P1, calib.P2, x1.T, x2.T)
    grid = (X[:3] / X[3]).T.reshape(pattern[1], pattern[0], 3)
    return np.concatenate([np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel(),
                           np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel()])


def _mono(corners1, corners2, image_size, pattern, square_mm):
    """Each camera alone: calibrateCamera's (rms, K, D, rvecs, tvecs) for camera 1, camera 2."""
    obj = [board_points(pattern, square_mm)] * len(corners1)
    return [cv2.calibrateCamera(obj, c, image_size, None, None, flags=_DISTORTION, criteria=_SOLVE)
            for c in (corners1, corners2)]


def _stereo(corners1, corners2, image_size, pattern, square_mm, mono):
    """The stereo fit from the cameras' own; stereoCalibrateExtended's outputs and per-pair RMS."""
    obj = [board_points(pattern, square_mm)] * len(corners1)
    out = cv2.stereoCalibrateExtended(obj, corners1, corners2, mono[0][1], mono[0][2], mono[1][1],
                                      mono[1][2], image_size, None, None,
                                      flags=cv2.CALIB_USE_INTRINSIC_GUESS | _DISTORTION, criteria=_SOLVE)
    rms, K1, D1, K2, D2, R, T = out[:7]
    per_view = np.asarray(out[-1]).reshape(-1, 2)
    per_pair = np.sqrt(np.mean(per_view**2, axis=1))
    return float(rms), K1, D1.ravel()[:5], K2, D2.ravel()[:5], R, T.ravel(), per_pair


def rig_agreement(mono) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pair: whether its rig (camera 2 from camera 1, from each camera's own pose of the board)
    agrees with the rig most pairs agree on, and how far off it is (deg, share of that baseline)."""
    (_, _, _, rv1, tv1), (_, _, _, rv2, tv2) = mono
    R1 = np.array([cv2.Rodrigues(r)[0] for r in rv1])
    R2 = np.array([cv2.Rodrigues(r)[0] for r in rv2])
    R = R2 @ R1.transpose(0, 2, 1)                                        # (n, 3, 3)
    T = np.array(tv2).reshape(-1, 3) - np.einsum("nij,nj->ni", R, np.array(tv1).reshape(-1, 3))
    cos = (np.einsum("iab,jab->ij", R, R) - 1.0) / 2.0                    # trace(Ri Rj^T) = 1 + 2 cos
    deg = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    share = np.linalg.norm(T[:, None] - T[None], axis=2) / max(float(np.median(np.linalg.norm(T, axis=1))), 1e-12)
    agree = (deg <= POSE_TOL_DEG) & (share <= POSE_TOL_SHARE)
    best = int(np.argmax(agree.sum(axis=1)))
    return agree[best], deg[best], share[best]


def calibrate_pairs(corners1: list[np.ndarray | None], corners2: list[np.ndarray | None],
                    image_size: tuple[int, int], pattern: tuple[int, int], square_mm: float, *,
                    outlier_factor: float = 3.0, outlier_floor_px: float = 0.5,
                    min_pairs: int = 3) -> ChessboardResult:
    """Stereo calibration from per-pair corners (None where the board was not found).

    image_size = (width, height). Raises NotEnoughPairs when fewer than ``min_pairs`` pairs have
    the board in both images (or agree on one rig), BadFit when the fit is over ``MAX_RMS_PX``.
    """
    pairs = []
    for i, (c1, c2) in enumerate(zip(corners1, corners2, strict=True)):
        missing = [side for side, c in (("left", c1), ("right", c2)) if c is None]
        reason = "used" if not missing else "board not found in " + (
            "both" if len(missing) == 2 else missing[0])
        pairs.append(PairReport(i, not missing, reason))
    used = [p.index for p in pairs if p.used]
    if len(used) < min_pairs:
        raise NotEnoughPairs(f"board found in both images of only {len(used)} of {len(pairs)} pairs, "
                             f"a calibration needs {min_pairs}", pairs)
    c1 = [np.asarray(corners1[i], np.float32) for i in used]
    c2 = [consistent_order(c1[k], np.asarray(corners2[i], np.float32)) for k, i in enumerate(used)]
    mono = _mono(c1, c2, image_size, pattern, square_mm)     # every view: a camera's own are all good
    agree, deg, share = rig_agreement(mono)
    for k, i in enumerate(used):
        if not agree[k]:
            pairs[i].used = False
            pairs[i].reason = (f"not one moment: its rig {deg[k]:.1f} deg and {share[k]:.0%} of the baseline "
                               "off the other pairs'")
    if agree.sum() < min_pairs:
        raise NotEnoughPairs(f"only {int(agree.sum())} of {len(pairs)} pairs agree on one rig, a calibration "
                             f"needs {min_pairs} (are left and right views of the same moments, in the same "
                             "order?)", pairs)
    used = [i for k, i in enumerate(used) if agree[k]]
    c1 = [c for c, k in zip(c1, agree, strict=True) if k]
    c2 = [c for c, k in zip(c2, agree, strict=True) if k]
    fit = _stereo(c1, c2, image_size, pattern, square_mm, mono)
    limit = max(outlier_factor * float(np.median(fit[-1])), outlier_floor_px)
    keep = fit[-1] <= limit
    for k, i in enumerate(used):
        pairs[i].rms_px = float(fit[-1][k])
        if not keep[k]:
            pairs[i].used = False
            pairs[i].reason = f"outlier: reprojection RMS {fit[-1][k]:.2f} px > {limit:.2f} px"
    if not keep.all() and keep.sum() >= min_pairs:
        c1 = [c for c, k in zip(c1, keep, strict=True) if k]
        c2 = [c for c, k in zip(c2, keep, strict=True) if k]
        fit = _stereo(c1, c2, image_size, pattern, square_mm, mono)
        for k, i in enumerate(p.index for p in pairs if p.used):
            pairs[i].rms_px = float(fit[-1][k])
    elif not keep.all():      # rejecting would leave too few: keep them all, say so
        for k, i in enumerate(used):
            pairs[i].used, pairs[i].reason = True, "used" if keep[k] else "used (high error, too few pairs)"
    if fit[0] > MAX_RMS_PX:
        raise BadFit(f"the pairs fit no rig: RMS reprojection error {fit[0]:.1f} px (a calibration is "
                     f"under ~1 px; over {MAX_RMS_PX:g} px the views do not belong together: pairs of "
                     "different moments, or another board)")
    return _result(fit, image_size, square_mm, pairs, c1, c2)


def _result(fit, image_size, square_mm, pairs, c1, c2) -> ChessboardResult:
    rms, K1, D1, K2, D2, R, T, _ = fit
    P1 = K1 @ np.c_[np.eye(3), np.zeros(3)]
    P2 = K2 @ np.c_[R, T]
    calib = StereoCalibration(P1=P1, P2=P2, K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T,
                              image_size=(int(image_size[0]), int(image_size[1])), rms_px=rms)
    F = fundamental_from_projections(P1, P2)
    epi = epipolar_error(c1, c2, K1, D1, K2, D2, F)
    return ChessboardResult(calib, rms, epi, pairs, square_mm, c1, c2)


def reference_stereo_calib(images1: list[np.ndarray], images2: list[np.ndarray],
                           pattern: tuple[int, int]) -> dict:
    """OpenCV's stereo_calib sample (samples/cpp/stereo_calib.cpp) step by step, as the yardstick:
    11x11 cornerSubPix, initCameraMatrix2D, stereoCalibrate with FIX_ASPECT_RATIO, ZERO_TANGENT_DIST,
    USE_INTRINSIC_GUESS, SAME_FOCAL_LENGTH, RATIONAL_MODEL, FIX_K3-K5; square = 1 unit.
    Returns rms_px, epipolar_px (its "average epipolar err"), baseline_squares, pairs used."""
    c1, c2 = [], []
    for a, b in zip(images1, images2, strict=True):
        found = [find_corners(img, pattern, fast_check=False, subpix_half=11) for img in (a, b)]
        if found[0] is not None and found[1] is not None:
            c1.append(found[0])
            c2.append(found[1])
    obj = [board_points(pattern, 1.0)] * len(c1)
    size = images1[0].shape[::-1]
    K1 = cv2.initCameraMatrix2D(obj, c1, size, 0)
    K2 = cv2.initCameraMatrix2D(obj, c2, size, 0)
    flags = (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_USE_INTRINSIC_GUESS
             | cv2.CALIB_SAME_FOCAL_LENGTH | cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_FIX_K3
             | cv2.CALIB_FIX_K4 | cv2.CALIB_FIX_K5)
    rms, K1, D1, K2, D2, _, T, _, F = cv2.stereoCalibrate(
        obj, c1, c2, K1, None, K2, None, size, flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-5))
    return {"rms_px": float(rms), "epipolar_px": epipolar_error(c1, c2, K1, D1, K2, D2, F),
            "baseline_squares": float(np.linalg.norm(T)), "pairs": len(c1)}
