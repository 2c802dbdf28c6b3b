"""Epipolar geometry between camera 1 and camera 2 from their perspective matrices."""
from __future__ import annotations

import numpy as np


def fundamental_from_projections(P1: np.ndarray, P2: np.ndarray) -> np.ndarray:
    """F (3, 3) with x2^T F x1 = 0, from P1, P2 (3, 4). Scaled to unit Frobenius norm."""
    C1 = np.linalg.svd(P1)[2][-1]                # camera 1 centre, homogeneous (4,)
    e2 = P2 @ C1                                 # epipole in image 2
    ex = np.array([[0, -e2[2], e2[1]], [e2[2], 0, -e2[0]], [-e2[1], e2[0], 0]])
    F = ex @ P2 @ np.linalg.pinv(P1)
    return F / np.linalg.norm(F)


def epipolar_lines(F: np.ndarray, pts1: np.ndarray) -> np.ndarray:
    """Lines (N, 3) in image 2, normalised so a^2 + b^2 = 1, for points (N, 2) of image 1."""
    pts1 = np.asarray(pts1, dtype=float).reshape(-1, 2)
    lines = np.c_[pts1, np.ones(len(pts1))] @ F.T
    return lines / np.hypot(lines[:, 0], lines[:, 1])[:, None]
