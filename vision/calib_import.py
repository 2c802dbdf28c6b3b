"""Stereo calibrations made by other tools, as a StereoCalibration (CALIB.json): the maths only.

Reading the files is the command line's (controller/cli/calibrate_import.py); here arrays come in.

- OpenCV (``stereoCalibrate``): K1 D1 K2 D2 R T with camera 2 <- camera 1 ``x2 = R x1 + T``. The
  world is camera 1's frame: P1 = K1 [I | 0], P2 = K2 [R | T] (as ``fishfarm calibrate chessboard``
  writes). T is in the board's square unit; ``mm_per_unit`` turns it into mm.
- DLT-11 (StereoMorph, Hedrick's DLTdv and other DLT tools): per camera
  u = (L1 x + L2 y + L3 z + L4) / (L9 x + L10 y + L11 z + 1), v = (L5 x + L6 y + L7 z + L8) / (same),
  i.e. P = [[L1 L2 L3 L4], [L5 L6 L7 L8], [L9 L10 L11 1]] (L12 = 1) in the tool's world unit.
- A plain pair of 3x4 matrices, pixel <- world unit; or CALIB.json's own form (P1, P2 with any of
  its optional fields: fishfarm's output read back), every field kept.

Pixels: CALIB.json uses OpenCV's convention (origin at the top-left pixel's centre, u right, v
down). ``pixel_transform`` maps another tool's convention onto it (origin at the top-left pixel's
corner, 1-based pixel indices, v up); P_opencv = A @ P_tool.

Every result goes through ``calibration_from_json``, so an import meets the same checks as any
CALIB.json (shapes, finite, invertible, a baseline); faults are CalibrationError naming the field.
"""
from __future__ import annotations

from typing import Literal

import numpy as np

from vision.calib_file import (
    CalibrationError,
    StereoCalibration,
    _check_camera_matrix,
    calibration_from_json,
    principal_point_outside,
)
from vision.triangulation import camera_centre

UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
MAX_BASELINE_MM = 1e9          # 1000 km: beyond, a unit or a typo (and the geometry's sums overflow)
PixelOrigin = Literal["zero", "corner", "one"]
# where the tool puts the top-left pixel's centre, in its own coordinates
_ORIGIN_OFFSET = {"zero": 0.0, "corner": 0.5, "one": 1.0}


def dlt11_to_projection(coeffs: np.ndarray, name: str = "P") -> np.ndarray:
    """The 3x4 perspective matrix of 11 DLT coefficients (L12 = 1)."""
    L = np.asarray(coeffs, dtype=float).reshape(-1)
    if L.size != 11:
        raise CalibrationError(name, f"{L.size} DLT coefficients, expected 11")
    return np.append(L, 1.0).reshape(3, 4)


def pixel_transform(origin: PixelOrigin = "zero", y_up: bool = False, height: int | None = None) -> np.ndarray:
    """3x3 A with (u, v, 1)_opencv = A (u, v, 1)_tool. ``origin``: where the tool's coordinates put
    the top-left pixel's centre: "zero" (0, 0) as OpenCV; "corner" (0.5, 0.5), coordinates measured
    from the image's corner; "one" (1, 1), 1-based pixel indices (R, MATLAB). ``y_up``: the tool's v
    grows upwards from the bottom row, which needs the image ``height``."""
    if origin not in _ORIGIN_OFFSET:
        raise ValueError(f"pixel origin {origin!r}: expected one of {sorted(_ORIGIN_OFFSET)}")
    d = _ORIGIN_OFFSET[origin]
    A = np.array([[1.0, 0.0, -d], [0.0, 1.0, -d], [0.0, 0.0, 1.0]])
    if y_up:
        if height is None:
            raise CalibrationError("image_size", "needed to turn a v-up pixel convention into OpenCV's")
        A = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, height - 1.0], [0.0, 0.0, 1.0]]) @ A
    return A


def world_to_mm(P: np.ndarray, mm_per_unit: float) -> np.ndarray:
    """P (pixel <- world in the tool's unit) as pixel <- world mm."""
    if not (np.isfinite(mm_per_unit) and mm_per_unit > 0):
        raise ValueError(f"mm per unit {mm_per_unit}: expected > 0")
    with np.errstate(all="ignore"):       # an overflow is a P "with NaN or infinity", refused by name
        return np.asarray(P, dtype=float) @ np.diag([1.0 / mm_per_unit] * 3 + [1.0])


def _check_centres(data: dict) -> None:
    """A camera centre beyond MAX_BASELINE_MM of the origin is a unit or a typo; refused before
    calibration_from_json, whose baseline check would overflow on it (numpy's warnings on stderr)."""
    for name in ("P1", "P2"):
        try:
            P = np.asarray(data.get(name), dtype=float)
        except (TypeError, ValueError, OverflowError):
            continue                          # calibration_from_json names it
        if P.shape != (3, 4) or not np.all(np.isfinite(P)):
            continue
        with np.errstate(all="ignore"):
            try:
                far = not np.abs(camera_centre(P)).max() <= MAX_BASELINE_MM
            except np.linalg.LinAlgError:
                continue                      # singular: calibration_from_json names it
        if far:
            raise CalibrationError(name, f"camera centre farther than {MAX_BASELINE_MM:g} mm from the world's "
                                         "origin: no rig is that wide (the file's unit?)")


def _checked(data: dict) -> StereoCalibration:
    data = {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in data.items() if v is not None}
    _check_centres(data)
    calib = calibration_from_json(data)
    if calib.image_size is not None:          # a size that cannot be the frames' (surveys would take them)
        w, h = calib.image_size
        outside = principal_point_outside(calib, w, h)
        if outside is not None:
            name, u, v = outside
            raise CalibrationError("image_size", f"{w}x{h} does not contain {name}'s principal point "
                                                 f"({u:.0f}, {v:.0f}): the calibration is for other images")
    return calib


def _size(image_size) -> list[int] | None:
    """[width, height] of whole pixels (the range is calibration_from_json's to check); a fraction,
    a flag or a non-number is refused, not truncated."""
    if image_size is None:
        return None
    out = []
    for v in image_size:
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)) \
                or not np.isfinite(v) or v != round(v):
            raise CalibrationError("image_size", f"{v!r}: not a whole number of pixels")
        out.append(int(v))
    return out


def from_projections(P1: np.ndarray, P2: np.ndarray, *, mm_per_unit: float = 1.0,
                     pixel: np.ndarray | None = None, image_size: tuple[int, int] | None = None,
                     extra: dict | None = None) -> StereoCalibration:
    """A calibration of two 3x4 matrices (pixel <- world unit), in mm and OpenCV's pixels."""
    A = np.eye(3) if pixel is None else pixel
    mats = {}
    for name, P in (("P1", P1), ("P2", P2)):
        P = np.asarray(P, dtype=float)
        if P.shape != (3, 4):
            raise CalibrationError(name, f"shape {list(P.shape)}, expected [3, 4]")
        mats[name] = A @ world_to_mm(P, mm_per_unit)
    return _checked({**mats, "image_size": _size(image_size), **(extra or {})})


def from_dlt11(coeffs: np.ndarray, *, mm_per_unit: float = 1.0, pixel: np.ndarray | None = None,
               image_size: tuple[int, int] | None = None, extra: dict | None = None) -> StereoCalibration:
    """A calibration of an (11, 2) table of DLT coefficients, one column per camera (left, right)."""
    table = np.asarray(coeffs, dtype=float)
    if table.shape != (11, 2):
        raise CalibrationError("coefficients", f"shape {list(table.shape)}, expected 11 rows x 2 cameras")
    return from_projections(dlt11_to_projection(table[:, 0], "P1"), dlt11_to_projection(table[:, 1], "P2"),
                            mm_per_unit=mm_per_unit, pixel=pixel, image_size=image_size, extra=extra)


ROTATION_ATOL = 2e-3      # R R^T against I: a rotation printed to 4 decimals strays 1e-4 (0.006 deg)


def _check_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation nearest R (SVD), for an R within rounding of one; CalibrationError otherwise."""
    if not np.allclose(R @ R.T, np.eye(3), atol=ROTATION_ATOL) or np.linalg.det(R) < 0:
        raise CalibrationError("R", "not a rotation matrix (R R^T != I or det(R) < 0)")
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def from_opencv(K1: np.ndarray, D1: np.ndarray | None, K2: np.ndarray, D2: np.ndarray | None,
                R: np.ndarray, T: np.ndarray, *, mm_per_unit: float = 1.0,
                image_size: tuple[int, int] | None = None, extra: dict | None = None) -> StereoCalibration:
    """OpenCV's stereo calibration: P1 = K1 [I | 0], P2 = K2 [R | T mm], world = camera 1's frame."""
    arrays = {"K1": K1, "K2": K2, "R": R, "T": T}
    shapes = {"K1": (3, 3), "K2": (3, 3), "R": (3, 3), "T": (3,)}
    for name, value in arrays.items():
        a = np.asarray(value, dtype=float)
        a = a.reshape(-1) if name == "T" else a
        if a.shape != shapes[name]:
            raise CalibrationError(name, f"shape {list(np.shape(value))}, expected {list(shapes[name])}")
        if not np.all(np.isfinite(a)):
            raise CalibrationError(name, "contains NaN or infinity")
        arrays[name] = a
    for name in ("K1", "K2"):                 # before P1/P2, which a bad K makes singular
        _check_camera_matrix(arrays[name], name)
    arrays["R"] = _check_rotation(arrays["R"])
    with np.errstate(all="ignore"):          # an overflow is refused by name below, not warned on stderr
        T_mm = arrays["T"] * mm_per_unit
        P1 = arrays["K1"] @ np.c_[np.eye(3), np.zeros(3)]
        P2 = arrays["K2"] @ np.c_[arrays["R"], T_mm]
        too_wide = not np.abs(T_mm).max() <= MAX_BASELINE_MM       # inf and nan too
    if too_wide or not np.all(np.isfinite(P2)):
        raise CalibrationError("T", f"{np.abs(arrays['T']).max():.3g} x {mm_per_unit:g} mm: no stereo rig is that "
                                    "wide (the file's unit?)")
    return _checked({"P1": P1, "P2": P2, "K1": arrays["K1"], "D1": D1, "K2": arrays["K2"], "D2": D2,
                     "R": arrays["R"], "T": T_mm, "image_size": _size(image_size), **(extra or {})})


def from_calibration(data: dict, *, mm_per_unit: float = 1.0, pixel: np.ndarray | None = None,
                     image_size: tuple[int, int] | None = None, extra: dict | None = None) -> StereoCalibration:
    """CALIB.json's own form, every field kept (a calibration read back must be the one written):
    P1, P2 and T from the world unit into mm, P1/P2 into OpenCV's pixels by ``pixel``. K and D are
    in OpenCV's pixels already: a ``pixel`` other than I with K1/K2 is the caller's to refuse."""
    _check_centres(data)
    calib = calibration_from_json(data)              # shapes, finite, D only with its K: checked first
    out = calib.to_json()
    A = np.eye(3) if pixel is None else pixel
    out["P1"], out["P2"] = (A @ world_to_mm(P, mm_per_unit) for P in (calib.P1, calib.P2))
    if calib.T is not None:
        out["T"] = calib.T * mm_per_unit
    if image_size is not None:
        out["image_size"] = _size(image_size)
    return _checked({**out, **(extra or {})})
