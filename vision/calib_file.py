"""CALIB.json's content: ``{"P1": 3x4, "P2": 3x4}`` plus optional K1, D1, K2, D2, R, T, image_size, rms_px.

A calibration with only P1 and P2 is valid input to every command. When D1/D2 are present,
pixel inputs are undistorted (with K1/K2) before any geometry.

Pure: the decoded JSON object in, ``StereoCalibration`` out, and back with ``to_json``; reading
and writing the file is the command line's (controller/cli/calib_io.py). ``calibration_from_json``
refuses what would make the geometry silently wrong, as ``CalibrationError`` naming the field:
P1/P2 missing or null, not 3x4, not finite, singular, or with one camera centre (no baseline:
nothing can be triangulated); K1/K2 singular or without the (0, 0, 1) last row that
cv2.undistortPoints assumes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from vision.triangulation import camera_centre


class CalibrationError(ValueError):
    """A calibration that cannot be used: ``field`` (None: the whole object) and ``fault``."""

    def __init__(self, field: str | None, fault: str):
        super().__init__(f"{field}: {fault}" if field else fault)
        self.field = field
        self.fault = fault


@dataclass
class StereoCalibration:
    P1: np.ndarray                       # (3, 4) pixel <- world mm, camera 1 (left)
    P2: np.ndarray                       # (3, 4) camera 2 (right)
    K1: np.ndarray | None = None         # (3, 3)
    D1: np.ndarray | None = None         # (k,) OpenCV distortion coefficients
    K2: np.ndarray | None = None
    D2: np.ndarray | None = None
    R: np.ndarray | None = None          # (3, 3) camera 2 <- camera 1
    T: np.ndarray | None = None          # (3,) mm
    image_size: tuple[int, int] | None = None   # (width, height)
    rms_px: float | None = None
    extra: dict = field(default_factory=dict)   # report fields kept verbatim

    def __post_init__(self):
        self.P1, self.P2 = _facing(self.P1), _facing(self.P2)

    @property
    def has_distortion(self) -> bool:
        return self.D1 is not None or self.D2 is not None

    def to_json(self) -> dict:
        out: dict = {"P1": self.P1.tolist(), "P2": self.P2.tolist()}
        for name in ("K1", "D1", "K2", "D2", "R", "T"):
            value = getattr(self, name)
            if value is not None:
                out[name] = np.asarray(value).tolist()
        if self.image_size is not None:
            out["image_size"] = list(self.image_size)
        if self.rms_px is not None:
            out["rms_px"] = float(self.rms_px)
        out.update(self.extra)
        return out


def _facing(P):
    """P scaled by the sign that makes det(P[:, :3]) positive (Hartley and Zisserman's convention):
    then a point before the camera has w > 0. A projection matrix is defined up to scale, sign
    included, and DLT or SVD tools give either; the survey read a negated one's cameras as looking
    backwards (its image-up reversed) and found no fish, silently."""
    if not isinstance(P, np.ndarray) or P.shape != (3, 4) or not np.all(np.isfinite(P)):
        return P                  # (refused where it is read: calibration_from_json)
    return -P if np.linalg.det(P[:, :3]) < 0 else P


MAX_IMAGE_PX = 100_000          # a side longer is no camera's: a unit or a typo
_SHAPES = {"P1": (3, 4), "P2": (3, 4), "K1": (3, 3), "K2": (3, 3), "R": (3, 3), "T": (3,)}


def has_bool(value, depth: int = 0) -> bool:
    """True/false anywhere in a (nested, up to 3 deep) list: numpy reads them as 1 and 0."""
    if isinstance(value, bool):
        return True
    return isinstance(value, list) and depth < 3 and any(has_bool(v, depth + 1) for v in value)


def _matrix(data: dict, name: str) -> np.ndarray | None:
    if name not in data or data[name] is None:
        return None
    if has_bool(data[name]):      # numpy reads true as 1: a 1 mm baseline
        raise CalibrationError(name, "not a numeric matrix (true/false in it)")
    try:
        m = np.asarray(data[name], dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise CalibrationError(name, "not a numeric matrix") from None
    if name in ("D1", "D2"):
        m = m.reshape(-1)
        if m.size not in (4, 5, 8, 12, 14):
            raise CalibrationError(name, f"{m.size} distortion coefficients (expected 4, 5, 8, 12 or 14)")
    elif name == "T":
        m = m.reshape(-1)
    if name in _SHAPES and m.shape != _SHAPES[name]:
        raise CalibrationError(name, f"shape {list(m.shape)}, expected {list(_SHAPES[name])}")
    if not np.all(np.isfinite(m)):
        raise CalibrationError(name, "contains NaN or infinity")
    return m


MIN_FOCAL_PX = 1.0
MAX_FOCAL_PX = 1e7


def _check_invertible(m: np.ndarray, name: str, what: str) -> None:
    scale = np.abs(m).max()
    if scale == 0 or np.linalg.matrix_rank(m, tol=1e-9 * scale) < 3:
        raise CalibrationError(name, f"singular: {what}")


def _check_camera_matrix(K: np.ndarray, name: str) -> None:
    """An intrinsic matrix must be invertible and end in (0, 0, 1): undistortion divides by it.
    Its focal lengths lie in [MIN_FOCAL_PX, MAX_FOCAL_PX] and its principal point within MAX_FOCAL_PX
    of the origin: a 0.001 px focal length imported and triangulated NaN; 1e12 px was called singular."""
    if np.allclose(K[2], [0.0, 0.0, 1.0], rtol=0.0, atol=1e-6) and K[0, 0] > 0 and K[1, 1] > 0:
        if not (MIN_FOCAL_PX <= K[0, 0] <= MAX_FOCAL_PX and MIN_FOCAL_PX <= K[1, 1] <= MAX_FOCAL_PX):
            raise CalibrationError(name, f"focal lengths fx {K[0, 0]:g}, fy {K[1, 1]:g} px: a camera's lie from "
                                         f"{MIN_FOCAL_PX:g} to {MAX_FOCAL_PX:g} px (is K in pixels?)")
        if np.abs(K[:2]).max() > MAX_FOCAL_PX:
            raise CalibrationError(name, f"{np.abs(K[:2]).max():g} in its first rows: beyond {MAX_FOCAL_PX:g} px, "
                                         "no camera's (is K in pixels?)")
    _check_invertible(K, name, "not an invertible camera matrix")
    if not np.allclose(K[2], [0.0, 0.0, 1.0], rtol=0.0, atol=1e-6):
        raise CalibrationError(name, f"last row {K[2].tolist()}, expected [0, 0, 1]")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise CalibrationError(name, f"focal lengths fx {K[0, 0]:g}, fy {K[1, 1]:g}: a camera matrix's are positive")
    if abs(K[1, 0]) > 1e-6 * K[1, 1]:
        raise CalibrationError(name, f"K[1][0] is {K[1, 0]:g}: a camera matrix is upper triangular")


def _check_baseline(P1: np.ndarray, P2: np.ndarray) -> None:
    """Two views from one centre see every point along the same ray: no depth, only garbage."""
    c1, c2 = camera_centre(P1), camera_centre(P2)
    baseline = float(np.linalg.norm(c2 - c1))
    if baseline <= 1e-6 * max(1.0, float(np.linalg.norm(c1)), float(np.linalg.norm(c2))):
        raise CalibrationError("P2", f"same camera centre as P1 ({np.round(c1, 3).tolist()}): no baseline, "
                                     "nothing can be triangulated")


# how far K1/K2, R and T may stray from P1/P2's own before the file is refused: beyond rounding and
# a refit's drift, within any real mix-up (another camera's K, a rectified P, mm against m)
AGREE_FOCAL = 0.02              # focal lengths, relative; the principal point and skew, in focal lengths
AGREE_ROTATION_DEG = 1.0
AGREE_T = 0.02                  # of |T|


def decompose(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K with a positive diagonal and K[2, 2] = 1, R a rotation, t) with P ~ K [R | t] up to scale."""
    P = _facing(np.asarray(P, float))
    K, R = cv2.RQDecomp3x3(P[:, :3])[1:3]
    flip = np.diag(np.sign(np.diag(K)))          # RQ's sign freedom: K's diagonal positive
    K, R = K @ flip, flip @ R
    scale = K[2, 2]
    K = K / scale
    return K, R, np.linalg.solve(K, P[:, 3] / scale)


def _check_agree(mats: dict) -> None:
    """K1/K2 are the cameras P1/P2 project through (undistortion uses K, triangulation P: two that
    disagree measure wrong), and R, T camera 2's pose from camera 1 as P1, P2 put them."""
    poses = [decompose(mats["P1"]), decompose(mats["P2"])]
    for name, (Kp, _, _) in (("K1", poses[0]), ("K2", poses[1])):
        K = mats[name]
        if K is None:
            continue
        f = np.array([K[0, 0], K[1, 1]])
        off = max(np.abs(np.array([Kp[0, 0], Kp[1, 1]]) / f - 1).max(),
                  np.abs(Kp[:2, 2] - K[:2, 2]).max() / f.min(), abs(Kp[0, 1] - K[0, 1]) / f.min())
        if not off <= AGREE_FOCAL:
            p = "P" + name[1]
            raise CalibrationError(name, f"not {p}'s camera: {p} has fx {Kp[0, 0]:.1f}, fy {Kp[1, 1]:.1f}, "
                                         f"centre ({Kp[0, 2]:.1f}, {Kp[1, 2]:.1f}) px, {name} "
                                         f"{K[0, 0]:.1f}, {K[1, 1]:.1f}, ({K[0, 2]:.1f}, {K[1, 2]:.1f})")
    (_, R1, t1), (_, R2, t2) = poses
    R, T = R2 @ R1.T, None
    if mats["R"] is not None:
        turn = math.degrees(math.acos(np.clip((np.trace(R @ mats["R"].T) - 1) / 2, -1.0, 1.0)))
        if not turn <= AGREE_ROTATION_DEG:
            raise CalibrationError("R", f"{turn:.1f} degrees from camera 2's rotation in P1, P2")
    if mats["T"] is not None:
        T = t2 - R @ t1
        if not np.linalg.norm(T - mats["T"]) <= AGREE_T * np.linalg.norm(T):
            raise CalibrationError("T", f"{np.round(mats['T'], 2).tolist()}, but P1, P2 put camera 2 at "
                                        f"{np.round(T, 2).tolist()} from camera 1 (same units as P)")


def calibration_from_json(data: object) -> StereoCalibration:
    """The calibration in a decoded CALIB.json object; CalibrationError at the first fault."""
    if not isinstance(data, dict):
        raise CalibrationError(None, "expected a JSON object with P1 and P2")
    for name in ("P1", "P2"):
        if data.get(name) is None:
            raise CalibrationError(name, "missing" if name not in data else "missing (null)")
    mats = {name: _matrix(data, name) for name in ("P1", "P2", "K1", "D1", "K2", "D2", "R", "T")}
    for name in ("P1", "P2"):
        _check_invertible(mats[name][:, :3], name, "its left 3x3 block has rank < 3")
    _check_baseline(mats["P1"], mats["P2"])
    for name in ("K1", "K2"):
        if mats[name] is not None:
            _check_camera_matrix(mats[name], name)
    for d, k in (("D1", "K1"), ("D2", "K2")):
        if mats[d] is not None and mats[k] is None:
            raise CalibrationError(d, f"distortion given without {k}")
    _check_agree(mats)
    size = data.get("image_size")
    if size is not None:
        # 1280.0 is a whole number too: a numpy array's tolist() writes sizes so
        if (not isinstance(size, list) or len(size) != 2
                or not all(isinstance(s, (int, float)) and not isinstance(s, bool) and 0 < s <= MAX_IMAGE_PX
                           and s == int(s) for s in size)):
            raise CalibrationError("image_size",
                                   f"expected [width, height] in pixels (whole numbers 1..{MAX_IMAGE_PX})")
        size = (int(size[0]), int(size[1]))
    rms = data.get("rms_px")
    if rms is not None and not (isinstance(rms, (int, float)) and not isinstance(rms, bool)
                                and abs(rms) < 1e300 and math.isfinite(rms)):
        raise CalibrationError("rms_px", "not a number")
    known = set(_SHAPES) | {"D1", "D2", "image_size", "rms_px"}
    extra = {k: v for k, v in data.items() if k not in known}
    return StereoCalibration(image_size=size, rms_px=rms, extra=extra, **mats)


def principal_point(calib: StereoCalibration, camera: int) -> np.ndarray:
    """Camera 1's or 2's principal point (u, v) in pixels: from K when given, else from P (where
    its principal axis, the third row's direction, meets the image)."""
    K = calib.K1 if camera == 1 else calib.K2
    if K is not None:
        return np.asarray(K, dtype=float)[:2, 2] / K[2, 2]
    M = np.asarray(calib.P1 if camera == 1 else calib.P2, dtype=float)[:, :3]
    x = M @ M[2]
    return x[:2] / x[2]


def check_image_size(calib: StereoCalibration, size: tuple[int, int]) -> None:
    """Refuse frames of ``size`` (width, height) the calibration was not made for.

    With ``image_size`` the sizes must be equal: pixels of another resolution (or a crop) are not
    the calibration's pixels. Without it (a file of only P1 and P2, a DLT import), the frames are
    accepted when both principal points lie inside them: any real camera's does, so a principal
    point outside means a calibration for bigger (or other) images. CalibrationError names
    ``image_size``, or ``P1``/``P2`` (``K1``/``K2`` when present) for a principal point outside.
    """
    width, height = int(size[0]), int(size[1])
    if calib.image_size is not None:
        if tuple(calib.image_size) != (width, height):
            cw, ch = calib.image_size
            raise CalibrationError("image_size", f"calibration made for {cw}x{ch} images, "
                                                 f"the frames are {width}x{height}")
        return
    outside = principal_point_outside(calib, width, height)
    if outside is not None:
        name, u, v = outside
        raise CalibrationError(name, f"principal point ({u:.0f}, {v:.0f}) outside the {width}x{height} "
                                     "frames: a calibration for other images (it has no image_size)")


def principal_point_outside(calib: StereoCalibration, width: int, height: int) -> tuple[str, float, float] | None:
    """The first camera whose principal point lies outside width x height pixels, as (the matrix it
    comes from: K1/K2, else P1/P2, u, v); None when both are inside. Any real camera's is inside."""
    for camera in (1, 2):
        u, v = principal_point(calib, camera)
        if not (0.0 <= u <= width - 1 and 0.0 <= v <= height - 1):
            name = f"K{camera}" if (calib.K1 if camera == 1 else calib.K2) is not None else f"P{camera}"
            return name, float(u), float(v)
    return None
