"""Epipolar geometry between camera 1 and camera 2 from their perspective matrices.

Two constructions of the same lines: the fundamental matrix F (``fundamental_from_projections``,
``epipolar_lines``) and the paper's eqs. (3)-(4), Ayache's M21, which gives each line as the
epipole e2 plus a direction (``epipoles``, ``paper_m21``, ``epipolar_directions``).

Convention (both calibrators write it): P gives a positive third homogeneous coordinate (depth) for
points in front of the camera, whatever the handedness of the world frame.
"""
from __future__ import annotations

import numpy as np

from vision.triangulation import camera_centre


def _cross_matrix(e: np.ndarray) -> np.ndarray:
    return np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])


def _adjugate(T: np.ndarray) -> np.ndarray:
    """adj(T) = det(T) T^-1 (3, 3) from the rows t1, t2, t3: columns t2 x t3, t3 x t1, t1 x t2."""
    t1, t2, t3 = T
    return np.column_stack([np.cross(t2, t3), np.cross(t3, t1), np.cross(t1, t2)])


def fundamental_from_projections(P1: np.ndarray, P2: np.ndarray) -> np.ndarray:
    """F (3, 3) with x2^T F x1 = 0, from P1, P2 (3, 4): [e2]x P2 P1^+. Scaled to unit Frobenius norm."""
    e2 = epipoles(P1, P2)[1]
    F = _cross_matrix(e2) @ P2 @ np.linalg.pinv(P1)
    return F / np.linalg.norm(F)


def epipolar_lines(F: np.ndarray, pts1: np.ndarray) -> np.ndarray:
    """Lines (N, 3) in image 2, normalised so a^2 + b^2 = 1, for points (N, 2) of image 1."""
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    lines = np.column_stack((pts1, np.ones(len(pts1)))) @ F.T
    return lines / np.hypot(lines[:, 0], lines[:, 1])[:, None]


def epipoles(P1: np.ndarray, P2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projective epipoles (3,) ``(U, V, S)``: e1 = image of camera 2's centre in image 1, e2 = image
    of camera 1's centre in image 2. Pixel position (U/S, V/S); S = 0 puts it at infinity."""
    P1 = np.asarray(P1, float)
    P2 = np.asarray(P2, float)
    C1 = np.append(camera_centre(P1), 1.0)
    C2 = np.append(camera_centre(P2), 1.0)
    return P1 @ C2, P2 @ C1


def _m21_factors(P1: np.ndarray, P2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """e2 (3,) and T2hat . adj(T1hat) (3, 3): the image in camera 2 of the vanishing point of the
    line of sight of (u1, v1, 1). M21 is the first turned into a direction from e2 to the second."""
    P1 = np.asarray(P1, float)
    P2 = np.asarray(P2, float)
    return epipoles(P1, P2)[1], P2[:, :3] @ _adjugate(P1[:, :3])


def _towards(e2: np.ndarray) -> np.ndarray:
    """[[S, 0, -U], [0, S, -V]] (2, 3): a homogeneous point x to S x3 (pixel(x) - pixel(e2))."""
    U, V, S = e2
    return np.array([[S, 0.0, -U], [0.0, S, -V]])


def paper_m21(P1: np.ndarray, P2: np.ndarray) -> np.ndarray:
    """The paper's M21 (2, 3), eq. (4): (du2, dv2) = M21 (u1, v1, 1) is the direction in image 2 of
    the epipolar line of (u1, v1), a line through the epipole e2.

    M21 = [[S, 0, -U], [0, S, -V]] . T2hat . [t2 x t3, t3 x t1, t1 x t2] with (U, V, S) = e2,
    T2hat = P2[:, :3] and t_i the rows of P1[:, :3]. The last factor is adj(T1hat): it sends
    (u1, v1, 1) to the direction of its line of sight; T2hat images that direction's vanishing
    point, and the first factor turns "from e2 to the vanishing point" into a pixel direction.
    Scaling P1 by a and P2 by b multiplies M21 by a^2 b^2 > 0, so M21 alone cannot tell which way
    along the line is "farther": ``epipolar_directions`` adds that from the sign of P1.
    """
    e2, vanishing = _m21_factors(P1, P2)
    return _towards(e2) @ vanishing


def _unit_directions(m21: np.ndarray, P1: np.ndarray, pts1: np.ndarray) -> np.ndarray:
    # adj(T1hat) = det(T1hat) T1hat^-1 and T1hat^-1 (u1, v1, 1) points to the front of camera 1 when
    # P1 gives positive depths (our convention): the sign of det turns M21 m1 towards "farther",
    # for a left-handed world frame (det < 0) as well as a right-handed one.
    d = np.column_stack((pts1, np.ones(len(pts1)))) @ m21.T
    d *= np.sign(np.linalg.det(np.asarray(P1, float)[:, :3]))
    return d / np.hypot(d[:, 0], d[:, 1])[:, None]


def epipolar_directions(P1: np.ndarray, P2: np.ndarray, pts1: np.ndarray) -> np.ndarray:
    """Unit directions (N, 2) in image 2 of the epipolar lines of points (N, 2) of image 1, by
    eq. (3), pointing the way the match moves as the point goes farther from camera 1. P1 must give
    positive depths in front of camera 1 (P2's sign does not matter)."""
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    return _unit_directions(paper_m21(P1, P2), P1, pts1)


def epipolar_lines_m21(P1: np.ndarray, P2: np.ndarray, pts1: np.ndarray) -> np.ndarray:
    """Lines (N, 3) in image 2 built the paper's way: through the epipole e2 along M21 m1.

    Same normalisation as ``epipolar_lines`` (a^2 + b^2 = 1); the normal is the direction turned by
    +90 degrees, so compare with F's lines up to sign. When e2 is at infinity (parallel axes) the
    lines are anchored instead at the image of the line of sight's point at infinity.
    """
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    e2, vanishing = _m21_factors(P1, P2)
    direction = _unit_directions(_towards(e2) @ vanishing, P1, pts1)
    normal = np.column_stack((-direction[:, 1], direction[:, 0]))
    if abs(e2[2]) > 1e-9 * np.hypot(e2[0], e2[1]):
        anchor = np.broadcast_to(e2, (len(pts1), 3))
    else:
        anchor = np.column_stack((pts1, np.ones(len(pts1)))) @ vanishing.T
    with np.errstate(divide="ignore", invalid="ignore"):
        c = -np.einsum("ij,ij->i", normal, anchor[:, :2]) / anchor[:, 2]
    return np.column_stack((normal, c))
