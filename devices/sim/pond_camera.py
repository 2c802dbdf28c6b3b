"""The tower camera's geometry: a pinhole on a tower looking down at the pond's water plane.

Pond frame: metres on the water plane (z = 0), x right / y up as in the pond drawing, z up out
of the water. A world point X maps to pixel ~ K (R X + t); pixels follow OpenCV's convention
(u column, v row, integer coordinates at pixel centres, so the image centre is ((w-1)/2, (h-1)/2)).
For points on the water the projection is the plane homography G = K [r1 r2 t]; ``H`` is its
exact inverse, pixel (u, v, 1) -> pond (x, y, 1), the TOWER.json the tracker reads.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

MARGIN = 0.06            # fraction of the frame left around the pond on each side (the bank)
FLOAT_SPACING_M = 0.40   # the float marker contract (DESIGN.md)
ORANGE_DIAMETER_M = 0.40
BLUE_DIAMETER_M = 0.20


@dataclass(frozen=True)
class FloatPose:
    """Where the float marker is: its orange centre (over the robot) and the robot's heading."""
    x_m: float
    y_m: float
    heading_rad: float

    def __post_init__(self):                  # plain floats, whatever numbers came in
        for name in ("x_m", "y_m", "heading_rad"):
            object.__setattr__(self, name, float(getattr(self, name)))

    def blue_xy(self) -> tuple[float, float]:
        """Centre of the blue disc, 0.40 m ahead along the heading."""
        return (self.x_m + FLOAT_SPACING_M * math.cos(self.heading_rad),
                self.y_m + FLOAT_SPACING_M * math.sin(self.heading_rad))


@dataclass(frozen=True, eq=False)
class TowerView:
    """A pinhole camera on a tower: pixel ~ K (R X + t) for world X (pond metres, z up)."""
    width: int
    height: int
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray

    @cached_property
    def G(self) -> np.ndarray:
        """3x3 pond (x, y, 1) -> pixel (u, v, 1) on the water plane (z = 0)."""
        G = np.asarray(self.K, float) @ np.c_[self.R[:, 0], self.R[:, 1], np.ravel(self.t)]
        return G / G[2, 2]

    @cached_property
    def H(self) -> np.ndarray:
        """3x3 pixel (u, v, 1) -> pond (x, y, 1): the exact inverse of the plane projection."""
        H = np.linalg.inv(self.G)
        return H / H[2, 2]

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    @property
    def centre_m(self) -> np.ndarray:
        """The camera's position in the pond frame (metres, z up)."""
        return -np.asarray(self.R, float).T @ np.ravel(self.t)

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) pond points on the water -> (N, 2) pixels."""
        return _apply(self.G, xy)

    def to_pond(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) pixels -> (N, 2) pond points where their rays meet the water."""
        return _apply(self.H, uv)

    def project(self, xyz: np.ndarray) -> np.ndarray:
        """(N, 3) world points (z up; below the water for reflections) -> (N, 2) pixels."""
        xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
        h = (xyz @ np.asarray(self.R, float).T + np.ravel(self.t)) @ np.asarray(self.K, float).T
        return h[:, :2] / h[:, 2:3]

    def depth(self, xyz: np.ndarray) -> np.ndarray:
        """(N,) distance of world points along the optical axis (positive in front)."""
        xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
        return (xyz @ np.asarray(self.R, float).T + np.ravel(self.t))[:, 2]


def _apply(M: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N, 2) points through the 3x3 homography M."""
    p = np.asarray(p, dtype=float).reshape(-1, 2)
    x, y = p[:, 0], p[:, 1]
    w = M[2, 0] * x + M[2, 1] * y + M[2, 2]
    return np.stack([(M[0, 0] * x + M[0, 1] * y + M[0, 2]) / w, (M[1, 0] * x + M[1, 1] * y + M[1, 2]) / w], -1)


def _look_along(fwd: np.ndarray) -> np.ndarray:
    """World -> camera rotation (rows: image right, image down, forward) for a camera looking
    along ``fwd``; the image's up is the world's z up, or the pond's +y looking straight down."""
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-6:
        right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    return np.vstack([right, np.cross(fwd, right), fwd])


def _in_front(R: np.ndarray, eye: np.ndarray, xy: np.ndarray) -> bool:
    return bool(np.all((np.c_[xy, np.zeros(len(xy))] - eye) @ R[2] > 1e-6))


def _aim(eye: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The rotation whose image of the outline is centred: from the outline's middle, turn a
    damped step at a time towards the ray through the middle of its image."""
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    fwd = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0]) - eye
    fwd /= np.linalg.norm(fwd)
    for _ in range(60):
        R = _look_along(fwd)
        n = _normalised(R, eye, xy)
        mid = (n.min(axis=0) + n.max(axis=0)) / 2
        if np.hypot(*mid) < 1e-10:
            break
        toward = R.T @ np.array([mid[0], mid[1], 1.0])
        toward /= np.linalg.norm(toward)
        step = 0.5
        while step > 1e-4:
            cand = fwd + step * (toward - fwd)
            cand /= np.linalg.norm(cand)
            if _in_front(_look_along(cand), eye, xy):
                break
            step /= 2
        fwd = cand
    return _look_along(fwd)


def _normalised(R: np.ndarray, eye: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(N, 2) normalised image coordinates (x/z, y/z) of pond points; ValueError behind the camera."""
    cam = (np.c_[xy, np.zeros(len(xy))] - eye) @ R.T
    if np.any(cam[:, 2] <= 1e-6):
        raise ValueError("the pond outline reaches behind the tower camera: raise the tower or move it back")
    return cam[:, :2] / cam[:, 2:3]


def tower_view(outline_xy, *, width: int = 1280, height: int = 720, tower_xy=None,
               tower_height_m: float = 8.0, hfov_deg: float | None = None) -> TowerView:
    """A tower camera that sees the whole pond outline with a margin of bank around it.

    ``tower_xy`` defaults to the middle of the south bank (below the outline's y), set back by
    2 m + 30 % of the pond's depth. The camera is aimed so the outline's image is centred, and
    its focal length (square pixels, principal point at the image centre) chosen to fit it with
    a 6 % margin; with ``hfov_deg`` the focal length is fixed and an outline that does not fit
    is a ValueError."""
    xy = np.asarray(outline_xy, dtype=float).reshape(-1, 2)
    if len(xy) < 3 or not np.all(np.isfinite(xy)):
        raise ValueError("the pond outline needs at least 3 finite (x, y) points")
    if int(width) < 16 or int(height) < 16:
        raise ValueError(f"frame {width}x{height} is too small (at least 16x16 pixels)")
    if not tower_height_m > 0:
        raise ValueError("tower_height_m must be above the water (> 0)")
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    if tower_xy is None:
        tower_xy = ((lo[0] + hi[0]) / 2, lo[1] - 2.0 - 0.3 * (hi[1] - lo[1]))
    eye = np.array([float(tower_xy[0]), float(tower_xy[1]), float(tower_height_m)])
    R = _aim(eye, xy)
    n = _normalised(R, eye, xy)
    half = np.maximum(np.abs(n).max(axis=0), 1e-9)
    w, h = int(width), int(height)
    fit = min((w - 1) / 2 * (1 - 2 * MARGIN) / half[0], (h - 1) / 2 * (1 - 2 * MARGIN) / half[1])
    if hfov_deg is None:
        f = fit
    else:
        if not 1.0 <= float(hfov_deg) < 179.0:
            raise ValueError(f"hfov_deg {hfov_deg} is outside 1..179 degrees")
        f = (w / 2) / math.tan(math.radians(float(hfov_deg)) / 2)
        if f > fit / (1 - 2 * MARGIN):
            raise ValueError(f"the pond does not fit in a {hfov_deg} degree view from this tower")
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    return TowerView(w, h, K, R, -R @ eye)
