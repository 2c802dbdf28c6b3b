"""Camera calibration by the direct linear transform (Ayache's method, paper eqs. (1)-(2)).

Each grid point (x, y, z) seen at pixel (u, v) gives the two linear equations of eq. (2) in the
12 entries of the 3x4 perspective matrix T. They are solved by least squares on Hartley-normalised
coordinates (centroid at the origin, mean distance sqrt(2) in the image and sqrt(3) in the world):
without it the system mixes entries of order 1 and 1e6 and the answer loses digits. The paper fixes
t34 = 1; we fix |T| = 1 instead (the smallest singular vector), which is the same least-squares
problem without the failure when t34 happens to be near 0.

The linear answer minimises an algebraic error. ``refine_projection`` then minimises the true
reprojection error in pixels (scipy least_squares, Levenberg-Marquardt): beyond the paper.

The validation report gives the fit on the grid itself and, since a grid's own figures cannot show
overfitting or a bad point, the same figures for points left out of the calibration (k-fold).
Neither can see what a grid that is nearly flat does off its plane, so ``check_grid`` refuses
grids thinner than MIN_THICKNESS_RATIO of their extent.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.distance import pdist

from vision.triangulation import normalise_projection, project, triangulate

MIN_POINTS = 6


class CalibrationInputError(ValueError):
    """The grid cannot determine a perspective matrix (too few, coplanar or collinear points...)."""


# Smallest off-plane spread accepted, as a fraction of the in-plane extent: the third singular value
# of the centred world points over the first (RMS distance from the best-fit plane over the RMS
# spread along the main axis). Measured on the simulated rig (100-point grid, validation points in
# the open book's volume at 0.02 px, 30 seeds; p95 of their distance errors, median over seeds and
# worst seed). Two 50-point layers of plate A d mm apart have ratio d / 287:
#   d = 2 / 5 / 10 mm   ratio 0.007 / 0.017 / 0.035   at 0.2 px: p95 10.7 / 4.3 / 2.1 %, worst 27 / 11 / 5.4 %
#   d = 15 / 30 / 50 mm ratio 0.052 / 0.104 / 0.174  at 0.2 px: p95 1.4 / 0.69 / 0.40 %, worst 3.6 / 1.7 / 1.0 %
#   open book           ratio 0.32                   at 0.2 px: p95 0.095 %, worst 0.15 %
#   flat plate, 0.3 mm of noise: ratio 0.002, p95 51 %, validation points ~420 mm off.
# The error goes as ~0.36 % x grid noise (px) / ratio. At 0.05 a grid measured to 0.1 px reaches the
# paper's 0.7 % (15 mm layers: 0.70 %; at 0.05 px 0.35 %), so a stricter bound would refuse usable
# grids, while everything thinner is refused: there 0.2 px of noise becomes percent errors and
# centimetres off the plate, with reprojection and held-out figures that look fine.
MIN_THICKNESS_RATIO = 0.05
# Below this the report warns: at the goal's 0.2 px the table above gives the paper's 0.7 % here.
THIN_GRID_RATIO = 0.1


def grid_shape(world: np.ndarray) -> dict:
    """RMS extent along the main axis and RMS thickness off the best-fit plane (mm), and their ratio."""
    world = np.asarray(world, dtype=float)
    s = np.linalg.svd(world - world.mean(axis=0), compute_uv=False) / np.sqrt(len(world))
    return {"extent_mm": float(s[0]), "width_mm": float(s[1]), "thickness_mm": float(s[2]),
            "thickness_ratio": float(s[2] / s[0]) if s[0] > 0 else 0.0}


def check_grid(world: np.ndarray, pixels: tuple[np.ndarray, ...] = (),
               min_ratio: float = MIN_THICKNESS_RATIO) -> None:
    """Raise CalibrationInputError when the world points cannot calibrate a camera.

    Collinear and (nearly) coplanar sets are found from the singular values of the centred points:
    the second (third) one below ``min_ratio`` of the first. A grid that is 3-D only by a few
    millimetres or by measurement noise reprojects well and still gives badly wrong 3-D off its
    plane: see MIN_THICKNESS_RATIO for the measurements behind the default.
    """
    world = np.asarray(world, dtype=float)
    if world.ndim != 2 or world.shape[1] != 3:
        raise CalibrationInputError(f"world points must be (N, 3), got {list(world.shape)}")
    if len(world) < MIN_POINTS:
        raise CalibrationInputError(f"{len(world)} points: at least {MIN_POINTS} non-coplanar are needed")
    arrays = (world, *pixels)
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise CalibrationInputError("NaN or infinite coordinate")
    shape = grid_shape(world)
    extent = shape["extent_mm"]
    need = f"at least {min_ratio:g} needed"
    if extent == 0:
        raise CalibrationInputError("degenerate: all world points coincide (they do not span a line)")
    if shape["width_mm"] < min_ratio * extent:
        raise CalibrationInputError(
            f"degenerate: the world points lie (nearly) on a line: spread across it {shape['width_mm']:.3g} mm "
            f"RMS over an extent of {extent:.4g} mm RMS (ratio {shape['width_mm'] / extent:.3f}, {need})")
    if shape["thickness_ratio"] < min_ratio:
        raise CalibrationInputError(
            f"(nearly) coplanar world points: off-plane thickness {shape['thickness_mm']:.3g} mm RMS over an "
            f"extent of {extent:.4g} mm RMS (ratio {shape['thickness_ratio']:.3f}, {need}); the DLT needs "
            "points well off a single plane")
    # a point listed twice (and so any set of fewer than MIN_POINTS distinct ones): a distance of 0
    # between them in the report (its relative error NaN) and a weight of two in the fit
    _, first, inverse = np.unique(world, axis=0, return_index=True, return_inverse=True)
    first_of = first[inverse.ravel()]                    # each point's first listing
    again = np.flatnonzero(first_of != np.arange(len(world)))
    if len(again):
        j = int(again[0])
        raise CalibrationInputError(f"points {int(first_of[j]) + 1} and {j + 1} are the same world point")
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
    """What ``fishfarm calibrate dlt`` prints: fit per camera, 3-D distance errors on the grid, the
    grid's shape, and the same errors out of sample (``holdout_check``)."""

    points: int
    rms_px: tuple[float, float]          # reprojection RMS, camera 1 and camera 2
    max_px: tuple[float, float]
    pairs: int                           # grid distances compared (all pairs of points)
    distance_error_pct: dict             # {"median", "p95", "max"} of |d_rec - d_true| / d_true
    triangulation_rms_px: float          # mean residual of eq. (6) over the grid
    grid: dict = field(default_factory=dict)     # ``grid_shape``: extent, thickness and their ratio
    out_of_sample: dict | None = None    # ``holdout_check``; None when not run or too few points

    def to_json(self) -> dict:
        return asdict(self)

    def text(self) -> str:
        d = self.distance_error_pct
        lines = [
            f"points: {self.points}",
            f"reprojection RMS: camera 1 {self.rms_px[0]:.3f} px (max {self.max_px[0]:.3f}), "
            f"camera 2 {self.rms_px[1]:.3f} px (max {self.max_px[1]:.3f})",
            f"3-D distances between grid points ({self.pairs} pairs), relative error: "
            f"median {d['median']:.4f} %, p95 {d['p95']:.4f} %, max {d['max']:.4f} %",
            f"triangulation residual: {self.triangulation_rms_px:.3f} px RMS",
        ]
        if self.grid:
            g = self.grid
            lines.append(f"grid shape: extent {g['extent_mm']:.1f} mm RMS, off-plane thickness "
                         f"{g['thickness_mm']:.1f} mm RMS (ratio {g['thickness_ratio']:.3f})")
            if g["thickness_ratio"] < THIN_GRID_RATIO:
                lines.append(f"warning: thin grid (ratio below {THIN_GRID_RATIO:g}): points off its plane are "
                             "measured less well than these figures say; spread the points further in depth")
        return "\n".join(lines + _holdout_text(self.out_of_sample))


def _holdout_text(o: dict | None) -> list[str]:
    if o is None:
        return ["held-out check: not run (switched off, or too few points to leave some out)"]
    e, d = o["point_error_mm"], o["distance_error_pct"]
    return [
        f"held-out check ({o['folds']} folds, {o['points']} points, each from a calibration that never "
        f"saw it): reprojection RMS camera 1 {o['rms_px'][0]:.3f} px (max {o['max_px'][0]:.3f}), "
        f"camera 2 {o['rms_px'][1]:.3f} px (max {o['max_px'][1]:.3f})",
        f"held-out 3-D: point error median {e['median']:.3f} mm, p95 {e['p95']:.3f} mm, max {e['max']:.3f} mm; "
        f"distances ({o['pairs']} pairs) median {d['median']:.4f} %, p95 {d['p95']:.4f} %, "
        f"max {d['max']:.4f} %",
    ]


def distance_errors_pct(true_points: np.ndarray, measured_points: np.ndarray) -> np.ndarray:
    """Relative error (%) of every pairwise distance, in scipy's condensed pair order."""
    d_true = pdist(true_points)
    return 100.0 * np.abs(pdist(measured_points) - d_true) / d_true


def error_summary(errors: np.ndarray) -> dict:
    median, p95 = np.percentile(errors, [50, 95])
    return {"median": float(median), "p95": float(p95), "max": float(errors.max())}


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2)))


def validation_report(P1: np.ndarray, P2: np.ndarray, world: np.ndarray, pix1: np.ndarray,
                      pix2: np.ndarray, out_of_sample: dict | None = None) -> ValidationReport:
    """Reprojection fit of each camera, and every grid distance reconstructed by triangulation."""
    e1, e2 = reprojection_errors(P1, world, pix1), reprojection_errors(P2, world, pix2)
    points, residual = triangulate(P1, P2, pix1, pix2)
    errors = distance_errors_pct(world, points)
    return ValidationReport(
        points=len(world),
        rms_px=(_rms(e1), _rms(e2)),
        max_px=(float(e1.max()), float(e2.max())),
        pairs=len(errors),
        distance_error_pct=error_summary(errors),
        triangulation_rms_px=_rms(residual),
        grid=grid_shape(world),
        out_of_sample=out_of_sample,
    )


def holdout_check(world: np.ndarray, pix1: np.ndarray, pix2: np.ndarray, refine: bool = True,
                  folds: int = 10, seed: int = 0) -> dict | None:
    """K-fold leave-out check: the points, shuffled (fixed seed, so the report is reproducible),
    are split in ``folds`` groups; each group is predicted by a calibration of the others. Gives the
    reprojection errors of the held-out pixels, the 3-D error of each held-out point (mm; the world
    frame is the grid's, so every calibration is in it) and the relative error of every distance
    between held-out reconstructions. The in-sample figures cannot show overfitting or a bad point;
    these do. None when leaving a group out would leave fewer than MIN_POINTS."""
    world, pix1, pix2 = (np.asarray(a, dtype=float) for a in (world, pix1, pix2))
    n = len(world)
    k = min(folds, n)
    group = np.random.default_rng(seed).permutation(n) % k
    if k < 2 or n - np.bincount(group).max() < MIN_POINTS:
        return None
    points, e1, e2 = np.full((n, 3), np.nan), np.full(n, np.nan), np.full(n, np.nan)
    for g in range(k):          # one calibration per fold: folds, not points, are looped over
        out = group == g
        try:
            P1 = calibrate_camera(world[~out], pix1[~out], refine)
            P2 = calibrate_camera(world[~out], pix2[~out], refine)
        except CalibrationInputError:
            continue            # the rest alone is degenerate: these points stay unpredicted
        e1[out] = reprojection_errors(P1, world[out], pix1[out])
        e2[out] = reprojection_errors(P2, world[out], pix2[out])
        points[out] = triangulate(P1, P2, pix1[out], pix2[out])[0]
    done = np.isfinite(e1) & np.all(np.isfinite(points), axis=1)
    if done.sum() < 2:
        return None
    distances = distance_errors_pct(world[done], points[done])
    return {
        "folds": k, "points": int(done.sum()),
        "rms_px": (_rms(e1[done]), _rms(e2[done])),
        "max_px": (float(e1[done].max()), float(e2[done].max())),
        "point_error_mm": error_summary(np.linalg.norm(points[done] - world[done], axis=1)),
        "pairs": len(distances),
        "distance_error_pct": error_summary(distances),
    }


def calibrate_stereo(world: np.ndarray, pix1: np.ndarray, pix2: np.ndarray, refine: bool = True,
                     folds: int = 10) -> tuple[np.ndarray, np.ndarray, ValidationReport]:
    """P1, P2 from one grid seen by both cameras, and the validation report on that grid, with a
    ``folds``-fold held-out check (0: none)."""
    world = np.asarray(world, dtype=float)
    pix1, pix2 = np.asarray(pix1, float), np.asarray(pix2, float)
    check_grid(world, (pix1, pix2))
    P1 = calibrate_camera(world, pix1, refine)
    P2 = calibrate_camera(world, pix2, refine)
    held_out = holdout_check(world, pix1, pix2, refine, folds) if folds else None
    return P1, P2, validation_report(P1, P2, world, pix1, pix2, held_out)
