"""Camera calibration by the direct linear transform (Ayache's method, paper eqs. (1)-(2)).

Each grid point (x, y, z) seen at pixel (u, v) gives the two linear equations of eq. (2) in the
12 entries of the 3x4 perspective matrix T. They are solved by least squares on Hartley-normalised
coordinates (centroid at the origin, mean distance sqrt(2) in the image and sqrt(3) in the world):
without it the system mixes entries of order 1 and 1e6 and the answer loses digits. The paper fixes
t34 = 1; we fix |T| = 1 instead (the smallest singular vector), which is the same least-squares
problem without the failure when t34 happens to be near 0.

The linear answer minimises an algebraic error. ``refine_projection`` then minimises the true
reprojection error in pixels (scipy least_squares, Levenberg-Marquardt): beyond the paper.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.distance import pdist

from vision.triangulation import normalise_projection, project, triangulate

MIN_POINTS = 6


class CalibrationInputError(ValueError):
    """The grid cannot determine a perspective matrix (too few, coplanar or collinear points...)."""


def check_grid(world: np.ndarray, pixels: tuple[np.ndarray, ...] = (), plane_tol: float = 1e-3) -> None:
    """Raise CalibrationInputError when the world points cannot calibrate a camera.

    Coplanar and collinear sets are found from the singular values of the centred points: the
    third (second) one is ~0 relative to the first. ``plane_tol`` is relative to the object's
    size; 1e-3 tolerates a flat plate measured to 0.1 mm over 100 mm and still calls it flat.
    """
    world = np.asarray(world, dtype=float)
    if world.ndim != 2 or world.shape[1] != 3:
        raise CalibrationInputError(f"world points must be (N, 3), got {list(world.shape)}")
    if len(world) < MIN_POINTS:
        raise CalibrationInputError(f"{len(world)} points: at least {MIN_POINTS} non-coplanar are needed")
    arrays = (world, *pixels)
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise CalibrationInputError("NaN or infinite coordinate")
    s = np.linalg.svd(world - world.mean(axis=0), compute_uv=False)
    if s[0] == 0 or s[1] <= plane_tol * s[0]:
        raise CalibrationInputError("degenerate: the world points lie on a line (or coincide)")
    if s[2] <= plane_tol * s[0]:
        raise CalibrationInputError("coplanar world points: the DLT needs points off a single plane")
    if len(np.unique(world, axis=0)) < MIN_POINTS:
        raise CalibrationInputError(f"fewer than {MIN_POINTS} distinct world points")
    for i, px in enumerate(pixels, start=1):
        ps = np.linalg.svd(px - px.mean(axis=0), compute_uv=False)
        if ps[0] == 0 or ps[1] <= 1e-6 * ps[0]:
            raise CalibrationInputError(f"degenerate: the pixels of camera {i} lie on a line")


def _similarity(points: np.ndarray) -> np.ndarray:
    """Hartley's normalising similarity for (N, d) points: (d+1, d+1) homogeneous matrix."""
    d = points.shape[1]
    centre = points.mean(axis=0)
    scale = np.sqrt(d) / np.mean(np.linalg.norm(points - centre, axis=1))
    S = np.eye(d + 1)
    S[:d, :d] *= scale
    S[:d, d] = -scale * centre
    return S


def _dlt_rows(world_h: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """The 2N x 12 system of eq. (2): rows [X^T, 0, -u X^T] and [0, X^T, -v X^T]."""
    n = len(world_h)
    zero = np.zeros((n, 4))
    u, v = pixels[:, :1], pixels[:, 1:2]
    return np.vstack([np.hstack([world_h, zero, -u * world_h]),
                      np.hstack([zero, world_h, -v * world_h])])


def dlt_projection(world: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Perspective matrix T (3, 4), pixel <- world, by linear least squares on normalised data."""
    world = np.asarray(world, dtype=float)
    pixels = np.asarray(pixels, dtype=float)
    check_grid(world, (pixels,))
    Sw, Si = _similarity(world), _similarity(pixels)
    world_n = np.c_[world, np.ones(len(world))] @ Sw.T
    pix_n = (np.c_[pixels, np.ones(len(pixels))] @ Si.T)[:, :2]
    A = _dlt_rows(world_n, pix_n)
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    if s[-2] <= 1e-9 * s[0]:        # a second null vector: the points do not fix T
        raise CalibrationInputError("degenerate: the points do not determine a unique perspective matrix")
    Tn = vt[-1].reshape(3, 4)
    return normalise_projection(np.linalg.inv(Si) @ Tn @ Sw, world)


def reprojection_errors(P: np.ndarray, world: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Pixel distance (N,) between the observed pixels and the projection of the world points."""
    return np.linalg.norm(project(P, world) - pixels, axis=1)


def refine_projection(P: np.ndarray, world: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Minimise the reprojection error in pixels over the 12 entries of P (Levenberg-Marquardt).

    Works in Hartley-normalised world coordinates so the parameters share one scale; the overall
    scale of P is a free direction that LM's damping simply leaves alone, and is reset at the end.
    """
    world = np.asarray(world, dtype=float)
    pixels = np.asarray(pixels, dtype=float)
    Sw = _similarity(world)
    world_n = np.c_[world, np.ones(len(world))] @ Sw.T
    p0 = P @ np.linalg.inv(Sw)
    p0 = p0 / np.linalg.norm(p0)

    def residuals(p: np.ndarray) -> np.ndarray:
        h = world_n @ p.reshape(3, 4).T
        return (h[:, :2] / h[:, 2:] - pixels).ravel()

    def jacobian(p: np.ndarray) -> np.ndarray:
        h = world_n @ p.reshape(3, 4).T
        w = h[:, 2:]
        uv = h[:, :2] / w
        J = np.zeros((len(world_n), 2, 12))
        J[:, 0, 0:4] = world_n / w
        J[:, 1, 4:8] = world_n / w
        J[:, :, 8:12] = -uv[:, :, None] * world_n[:, None, :] / w[:, :, None]
        return J.reshape(-1, 12)

    fit = least_squares(residuals, p0.ravel(), jac=jacobian, method="lm", x_scale="jac")
    return normalise_projection(fit.x.reshape(3, 4) @ Sw, world)


def calibrate_camera(world: np.ndarray, pixels: np.ndarray, refine: bool = True) -> np.ndarray:
    """DLT (eq. 2) then, unless ``refine`` is False, reprojection-error refinement."""
    P = dlt_projection(world, pixels)
    return refine_projection(P, world, pixels) if refine else P


@dataclass
class ValidationReport:
    """What ``fishfarm calibrate dlt`` prints: fit per camera and 3-D distance errors."""

    points: int
    rms_px: tuple[float, float]          # reprojection RMS, camera 1 and camera 2
    max_px: tuple[float, float]
    pairs: int                           # grid distances compared (all pairs of points)
    distance_error_pct: dict             # {"median", "p95", "max"} of |d_rec - d_true| / d_true
    triangulation_rms_px: float          # mean residual of eq. (6) over the grid

    def to_json(self) -> dict:
        return asdict(self)

    def text(self) -> str:
        d = self.distance_error_pct
        return "\n".join([
            f"points: {self.points}",
            f"reprojection RMS: camera 1 {self.rms_px[0]:.3f} px (max {self.max_px[0]:.3f}), "
            f"camera 2 {self.rms_px[1]:.3f} px (max {self.max_px[1]:.3f})",
            f"3-D distances between grid points ({self.pairs} pairs), relative error: "
            f"median {d['median']:.4f} %, p95 {d['p95']:.4f} %, max {d['max']:.4f} %",
            f"triangulation residual: {self.triangulation_rms_px:.3f} px RMS",
        ])


def distance_errors_pct(true_points: np.ndarray, measured_points: np.ndarray) -> np.ndarray:
    """Relative error (%) of every pairwise distance, in scipy's condensed pair order."""
    d_true = pdist(true_points)
    return 100.0 * np.abs(pdist(measured_points) - d_true) / d_true


def error_summary(errors_pct: np.ndarray) -> dict:
    median, p95 = np.percentile(errors_pct, [50, 95])
    return {"median": float(median), "p95": float(p95), "max": float(errors_pct.max())}


def validation_report(P1: np.ndarray, P2: np.ndarray, world: np.ndarray, pix1: np.ndarray,
                      pix2: np.ndarray) -> ValidationReport:
    """Reprojection fit of each camera, and every grid distance reconstructed by triangulation."""
    e1, e2 = reprojection_errors(P1, world, pix1), reprojection_errors(P2, world, pix2)
    points, residual = triangulate(P1, P2, pix1, pix2)
    errors = distance_errors_pct(world, points)
    return ValidationReport(
        points=len(world),
        rms_px=(float(np.sqrt(np.mean(e1 ** 2))), float(np.sqrt(np.mean(e2 ** 2)))),
        max_px=(float(e1.max()), float(e2.max())),
        pairs=len(errors),
        distance_error_pct=error_summary(errors),
        triangulation_rms_px=float(np.sqrt(np.mean(residual ** 2))),
    )


def calibrate_stereo(world: np.ndarray, pix1: np.ndarray, pix2: np.ndarray,
                     refine: bool = True) -> tuple[np.ndarray, np.ndarray, ValidationReport]:
    """P1, P2 from one grid seen by both cameras, and the validation report on that grid."""
    world = np.asarray(world, dtype=float)
    check_grid(world, (np.asarray(pix1, float), np.asarray(pix2, float)))
    P1 = calibrate_camera(world, pix1, refine)
    P2 = calibrate_camera(world, pix2, refine)
    return P1, P2, validation_report(P1, P2, world, pix1, pix2)
