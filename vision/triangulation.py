"""3-D reconstruction of matched pixel pairs: least squares of the paper's eq. (6), batched.

Eq. (6) gives four linear equations ``a_k . (X, 1) = 0`` in the world point X, with
``a = t_1 - u t_3`` and ``t_2 - v t_3`` for each camera (t_i: rows of the perspective matrix).
Their normal equations ``M X = b`` (3x3) are, summed over the four rows,

    M|b  =  sum_cameras  [1, u, v, u^2 + v^2] . [Q11 + Q22, -(Q13 + Q31), -(Q23 + Q32), Q33]

with ``Qij = t_i t_j^T`` constant per camera: so for N points the 9 distinct entries of every
M|b come out of one (9, 8) x (8, N) matrix product, and the 3x3 solve is Cramer's rule on
arrays. No loop over points, no per-point LAPACK call.

With each P scaled so its third row has a unit direction, the equations' residuals are
"pixel error x depth", so both cameras weigh alike when their depths are alike (the paper's
convergent rig). ``iterations=1`` reweights once by 1/depth, making the solution the pixel-error
least squares to first order (Hartley & Sturm's iterative linear method) for rigs whose cameras
see the scene at very different depths; it costs about 40 % of the throughput and changed
nothing measurable on the simulated rig, so the default is the paper's plain least squares.
"""
from __future__ import annotations

import functools
import math

import cv2
import numpy as np

_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2), (0, 3), (1, 3), (2, 3))


def normalise_projection(P: np.ndarray, points: np.ndarray | None = None) -> np.ndarray:
    """P scaled so its third row's first three entries have unit norm (the third homogeneous
    coordinate is then the depth in mm) and signed so the depth is positive: in front of the
    camera for ``points`` when given, else det(P[:, :3]) > 0 (true for a right-handed world)."""
    P = np.asarray(P, dtype=float)
    P = P / np.linalg.norm(P[2, :3])
    if points is not None:
        depth = np.column_stack((points, np.ones(len(points)))) @ P[2]
        sign = np.sign(np.median(depth))
    else:
        sign = np.sign(np.linalg.det(P[:, :3]))
    return P * (sign if sign != 0 else 1.0)


def camera_centre(P: np.ndarray) -> np.ndarray:
    """Optical centre (3,) in world units: the null vector of P."""
    P = np.asarray(P, dtype=float)
    return -np.linalg.solve(P[:, :3], P[:, 3])


def project(P: np.ndarray, world: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of world points (N, 3) through a perspective matrix (no distortion)."""
    world = np.asarray(world, dtype=float).reshape(-1, 3)
    h = world @ P[:, :3].T + P[:, 3]
    return h[:, :2] / h[:, 2:]


def _camera_block(P: np.ndarray) -> np.ndarray:
    """(4, 9): the rows for features [1, u, v, u^2+v^2] of one camera (see module docstring)."""
    Q = np.einsum("ai,bj->abij", P, P)                 # Q[a, b] = t_a t_b^T, 4x4 each
    terms = (Q[0, 0] + Q[1, 1], -(Q[0, 2] + Q[2, 0]), -(Q[1, 2] + Q[2, 1]), Q[2, 2])
    return np.array([[term[i, j] for i, j in _UPPER] for term in terms])


def _solve_normal(mb: np.ndarray) -> np.ndarray:
    """Solve every symmetric 3x3 system M X = -c, given as rows (9, N): m00 m01 m02 m11 m12 m22 c0
    c1 c2. Returns X as rows (3, N)."""
    m00, m01, m02, m11, m12, m22, c0, c1, c2 = mb
    a00 = m11 * m22 - m12 * m12
    a01 = m02 * m12 - m01 * m22
    a02 = m01 * m12 - m02 * m11
    a11 = m00 * m22 - m02 * m02
    a12 = m01 * m02 - m00 * m12
    a22 = m00 * m11 - m01 * m01
    det = m00 * a00 + m01 * a01 + m02 * a02
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = -1.0 / det                 # a singular system (point on the baseline) gives inf/NaN
        X = np.empty((3, mb.shape[1]))
        np.multiply(a00 * c0 + a01 * c1 + a02 * c2, inv, out=X[0])
        np.multiply(a01 * c0 + a11 * c1 + a12 * c2, inv, out=X[1])
        np.multiply(a02 * c0 + a12 * c1 + a22 * c2, inv, out=X[2])
    return X


def _features(uv1: np.ndarray, uv2: np.ndarray, w1=1.0, w2=1.0) -> np.ndarray:
    """Rows (8, N): [1, u, v, u^2+v^2] of camera 1 then camera 2, each times its weight."""
    F = np.empty((8, uv1.shape[1]))
    for k, (uv, w) in enumerate(((uv1, w1), (uv2, w2))):
        u, v = uv
        F[4 * k] = w
        np.multiply(u, w, out=F[4 * k + 1])
        np.multiply(v, w, out=F[4 * k + 2])
        np.multiply(u * u + v * v, w, out=F[4 * k + 3])
    return F


def _project_rows(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    h = P[:, :3] @ X + P[:, 3:]
    return h[:2] / h[2]


def triangulate(P1: np.ndarray, P2: np.ndarray, pts1: np.ndarray, pts2: np.ndarray,
                iterations: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) from pixel pairs (N, 2) + (N, 2), and residual_px (N,): the RMS over
    both images of the distance between each pixel and the reprojected point.

    Pixels must already be undistorted (see ``triangulate_calibrated``). Pairs whose equations
    are singular (a point on the baseline) come out as NaN.
    """
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    pts2 = np.asarray(pts2, dtype=float).reshape(-1, 2)
    if len(pts1) != len(pts2):
        raise ValueError(f"{len(pts1)} points in image 1 but {len(pts2)} in image 2")
    uv1, uv2 = np.ascontiguousarray(pts1.T), np.ascontiguousarray(pts2.T)    # rows: fast columns
    # Work with the origin at camera 1's centre: keeps the translation column small, so the
    # normal equations do not lose digits when the world origin is far from the rig.
    origin = camera_centre(P1)
    shift = np.eye(4)
    shift[:3, 3] = origin
    Ps = [normalise_projection(P @ shift) for P in (P1, P2)]
    Gt = np.vstack([_camera_block(P) for P in Ps]).T                 # (9, 8)
    X = _solve_normal(Gt @ _features(uv1, uv2))
    for _ in range(iterations):
        w1, w2 = (1.0 / (P[2, :3] @ X + P[2, 3]) ** 2 for P in Ps)   # 1 / depth^2 per camera
        X = _solve_normal(Gt @ _features(uv1, uv2, w1, w2))
    d1 = _project_rows(Ps[0], X) - uv1
    d2 = _project_rows(Ps[1], X) - uv2
    residual = np.sqrt(0.5 * (d1[0] ** 2 + d1[1] ** 2 + d2[0] ** 2 + d2[1] ** 2))
    X += origin[:, None]
    return np.ascontiguousarray(X.T), residual


# cv2.undistortPoints' fixed-point iterations: its default 5 leaves an action camera's corners (k1 -0.32 at
# f 900 px, 1920x1080) 1-3 px off, metres in depth; 40 converge to 1e-12 px there, ~0.7 us a point
UNDISTORT_ITERATIONS = 40


def undistort_pixels(pts: np.ndarray, K: np.ndarray, D: np.ndarray | None) -> np.ndarray:
    """Ideal pinhole pixels (N, 2) of distorted pixels, in the same camera matrix K; NaN where the
    lens model has no ray for the pixel (beyond ``distortion_reach``: the model folds back there).

    Pixels are taken to normalised coordinates with the whole inverse of K first:
    cv2.undistortPoints reads fx, fy, cx, cy and ignores K's skew, which P = K [R|t] then puts back
    (a skewed K with D all zeros moved a pixel 7 px). The skew applies after the distortion, as in
    the Caltech / MATLAB model OpenCV's own leaves it out of."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    if D is None or len(pts) == 0:
        return pts
    K, D = np.asarray(K, float), np.asarray(D, float)
    seen = _homogeneous(pts) @ np.linalg.inv(K).T
    seen = seen[:, :2] / seen[:, 2:3]
    ideal = cv2.undistortPoints(seen.reshape(-1, 1, 2), np.eye(3), D, R=None, P=None,
                                criteria=(cv2.TERM_CRITERIA_COUNT, UNDISTORT_ITERATIONS, 0.0)).reshape(-1, 2)
    out = _homogeneous(ideal) @ K.T
    out = out[:, :2] / out[:, 2:3]
    out[np.hypot(seen[:, 0], seen[:, 1]) >= distortion_reach(tuple(D.ravel()))] = np.nan
    return out


def _homogeneous(pts: np.ndarray) -> np.ndarray:
    return np.column_stack([pts, np.ones(len(pts))])


REACH_MAX_R = 10.0     # normalised ideal radius looked at (84 deg off axis): beyond is no camera here


@functools.lru_cache(maxsize=64)
def distortion_reach(D: tuple[float, ...]) -> float:
    """The largest normalised distorted radius OpenCV's radial model (k1, k2, k3 over k4, k5, k6)
    reaches before it folds back (inf when it does not, out to ``REACH_MAX_R``). A model fitted to a
    board that never reached the image's corners can fold inside the image: pixels beyond have no
    ray, and undistortPoints returns them as they were (a 0 px residual on nonsense). With the
    tangential and prism terms left out (small where a model is usable) and a 0.1 % margin."""
    k = np.zeros(8)
    k[:min(len(D), 8)] = D[:8]
    k1, k2, p1, p2, k3, k4, k5, k6 = k
    r = np.linspace(0.0, REACH_MAX_R, 20001)
    r2 = r * r
    den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    rd = r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / np.where(den > 0, den, np.nan)
    bad = np.flatnonzero(~(np.diff(rd) > 0))
    if len(bad) == 0:
        return math.inf
    return float(rd[bad[0]]) * 0.999


def reach_in_image(K: np.ndarray, D: np.ndarray | None, image_size: tuple[int, int]) -> tuple[float, float] | None:
    """(reach, farthest corner) in pixels from the principal point when the lens model folds back
    inside a (width, height) image (pixels beyond the reach are not measured), else None. The
    reach is along x, in fx's pixels."""
    if D is None:
        return None
    reach = distortion_reach(tuple(np.asarray(D, float).ravel()))
    K = np.asarray(K, float)
    w, h = image_size
    corners = _homogeneous(np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]))
    seen = corners @ np.linalg.inv(K).T
    radius = np.hypot(seen[:, 0] / seen[:, 2], seen[:, 1] / seen[:, 2])
    if radius.max() < reach:
        return None
    corner_px = float(np.max(np.hypot(*(corners[:, :2] - K[:2, 2]).T)))
    return reach * float(K[0, 0]), corner_px


def triangulate_calibrated(calib, pts1: np.ndarray, pts2: np.ndarray,
                           iterations: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``triangulate`` with a StereoCalibration: undistorts first when it has D1/D2. The residual is
    then measured on the undistorted pixels."""
    if calib.has_distortion:
        pts1 = undistort_pixels(pts1, calib.K1, calib.D1)
        pts2 = undistort_pixels(pts2, calib.K2, calib.D2)
    return triangulate(calib.P1, calib.P2, pts1, pts2, iterations)
