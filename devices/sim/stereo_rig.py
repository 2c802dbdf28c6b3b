"""Simulated convergent stereo rig and two-plane calibration object (the paper's section 3).

The rig: two pinhole cameras (1280x960 by default) side by side, each turned inwards so the
optical axes cross ``crossing_mm`` ahead of the midpoint between them (1 m, as in the paper).
The calibration object: two perpendicular aluminium plates hinged on a vertical edge (the
classic Ayache/Faugeras "open book"), each carrying a grid of points at several heights,
100 points in all. World frame = the object's frame, millimetres, z up, the hinge on the z axis,
plate A in the x-z plane (y = 0) and plate B in the y-z plane (x = 0).

All randomness comes from a caller's ``numpy.random.Generator`` so tests are reproducible.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from vision.calib_file import StereoCalibration


def two_plane_object(cols: int = 10, rows: int = 5, pitch_mm: float = 50.0,
                     margin_mm: float = 50.0) -> np.ndarray:
    """Grid points (2*cols*rows, 3) in mm: plate A (y = 0) then plate B (x = 0).

    Columns run away from the hinge starting ``margin_mm`` from it (the hinge itself carries no
    points, so no point is shared); rows are the heights z = 0, pitch, 2*pitch, ...
    """
    along = margin_mm + pitch_mm * np.arange(cols)
    height = pitch_mm * np.arange(rows)
    a, z = (g.ravel() for g in np.meshgrid(along, height))
    zero = np.zeros_like(a)
    plate_a = np.c_[a, zero, z]
    plate_b = np.c_[zero, a, z]
    return np.vstack([plate_a, plate_b])


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t (camera <- world) of a camera at ``eye`` looking at ``target``.

    OpenCV camera frame: x right, y down, z forward. ``up`` is the world direction that should
    appear upwards in the image.
    """
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)            # right = forward x up  (y down makes the frame right-handed)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    return R, -R @ eye


def _rodrigues(R: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(R, dtype=float))[0].ravel()


@dataclass
class StereoRig:
    """Two calibrated pinhole cameras. ``R``/``t`` of each camera map world mm to camera mm."""

    K1: np.ndarray
    K2: np.ndarray
    R1: np.ndarray
    t1: np.ndarray
    R2: np.ndarray
    t2: np.ndarray
    image_size: tuple[int, int] = (1280, 960)
    D1: np.ndarray | None = None
    D2: np.ndarray | None = None
    target: np.ndarray = field(default_factory=lambda: np.zeros(3))   # where the axes cross

    @property
    def P1(self) -> np.ndarray:
        return self.K1 @ np.c_[self.R1, self.t1]

    @property
    def P2(self) -> np.ndarray:
        return self.K2 @ np.c_[self.R2, self.t2]

    @property
    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Optical centres of camera 1 and 2 in world mm."""
        return -self.R1.T @ self.t1, -self.R2.T @ self.t2

    def project(self, world: np.ndarray, noise_px: float = 0.0,
                rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) of world points (N, 3) in camera 1 and 2, distorted if D is set,
        plus independent Gaussian noise of ``noise_px`` standard deviation per coordinate."""
        world = np.asarray(world, dtype=float).reshape(-1, 3)
        out = []
        for K, D, R, t in ((self.K1, self.D1, self.R1, self.t1), (self.K2, self.D2, self.R2, self.t2)):
            dist = np.zeros(5) if D is None else np.asarray(D, dtype=float)
            px = cv2.projectPoints(world, _rodrigues(R), np.asarray(t, dtype=float), K, dist)[0]
            out.append(px.reshape(-1, 2))
        if noise_px > 0:
            if rng is None:
                raise ValueError("noise_px > 0 needs a numpy Generator (rng) for reproducibility")
            out = [px + rng.normal(0.0, noise_px, px.shape) for px in out]
        return out[0], out[1]

    def depths(self, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance along each optical axis (mm) of world points (N, 3): positive = in front."""
        world = np.asarray(world, dtype=float).reshape(-1, 3)
        return world @ self.R1[2] + self.t1[2], world @ self.R2[2] + self.t2[2]

    def in_view(self, world: np.ndarray, border_px: float = 0.0) -> np.ndarray:
        """(N,) bool: the point is in front of both cameras and inside both images."""
        u1, u2 = self.project(world)
        w, h = self.image_size
        inside = [(p[:, 0] >= border_px) & (p[:, 0] <= w - 1 - border_px)
                  & (p[:, 1] >= border_px) & (p[:, 1] <= h - 1 - border_px) for p in (u1, u2)]
        z1, z2 = self.depths(world)
        return inside[0] & inside[1] & (z1 > 0) & (z2 > 0)

    def calibration(self) -> StereoCalibration:
        """The true calibration, in CALIB.json form (R, T: camera 2 <- camera 1)."""
        R = self.R2 @ self.R1.T
        T = self.t2 - R @ self.t1
        return StereoCalibration(P1=self.P1, P2=self.P2, K1=self.K1.copy(), K2=self.K2.copy(),
                                 D1=None if self.D1 is None else np.asarray(self.D1, float),
                                 D2=None if self.D2 is None else np.asarray(self.D2, float),
                                 R=R, T=T, image_size=self.image_size)


def intrinsics(focal_px: float, image_size: tuple[int, int]) -> np.ndarray:
    """Square pixels, no skew, principal point at the image centre (OpenCV pixel convention)."""
    w, h = image_size
    return np.array([[focal_px, 0.0, (w - 1) / 2], [0.0, focal_px, (h - 1) / 2], [0.0, 0.0, 1.0]])


def convergent_rig(baseline_mm: float = 400.0, crossing_mm: float = 1000.0, focal_px: float = 1400.0,
                   image_size: tuple[int, int] = (1280, 960), target: np.ndarray | None = None,
                   forward: np.ndarray | None = None, up: np.ndarray | None = None,
                   distortion: np.ndarray | None = None) -> StereoRig:
    """A convergent rig whose optical axes cross at ``target`` (world mm), ``crossing_mm`` from the
    midpoint of the cameras, which sits back along ``forward``.

    Defaults place it in front of the default two-plane object's inside corner, looking at the
    centroid of its points from 45 degrees between the plates and 30 degrees above; the grid then
    fills ~90 % of the image width. The 400 mm baseline (23 degree vergence at 1 m) was chosen on
    the DLT accuracy goal: depth error goes as Z^2 / (f B) per pixel, and over 20 seeded runs
    (grid at 0.2 px, validation points at 0.02 px, as in bench/bench_stereo.py) 300/400/500 mm gave p95
    errors of the distances between validation points of 0.14/0.10/0.09 %: 400 mm is
    where the gain flattens while both cameras still see both plates at a similar scale, which
    matching needs.
    """
    target = two_plane_object().mean(axis=0) if target is None else np.asarray(target, float)
    if forward is None:        # from the viewer towards the corner: down 30 deg, along -(x+y)
        forward = np.array([-np.cos(np.radians(30)) / np.sqrt(2)] * 2 + [-np.sin(np.radians(30))])
    forward = np.asarray(forward, float) / np.linalg.norm(forward)
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, float)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    middle = target - crossing_mm * forward
    K = intrinsics(focal_px, image_size)
    cams = [look_at(middle + side * baseline_mm / 2 * right, target, up) for side in (-1, 1)]
    D = None if distortion is None else np.asarray(distortion, float)
    return StereoRig(K1=K, K2=K.copy(), R1=cams[0][0], t1=cams[0][1], R2=cams[1][0], t2=cams[1][1],
                     image_size=image_size, D1=D, D2=None if D is None else D.copy(), target=target)


def measure_grid(rig: StereoRig, world: np.ndarray, noise_px: float,
                 rng: np.random.Generator) -> np.ndarray:
    """GRID.csv rows (N, 7): ``x_mm, y_mm, z_mm, u1, v1, u2, v2`` with noisy pixels."""
    p1, p2 = rig.project(world, noise_px, rng)
    return np.c_[world, p1, p2]


def random_points_in_grid_volume(world: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points drawn uniformly in the axis-aligned box of the grid points (the volume the
    calibration covers): validation points that the calibration never saw."""
    lo, hi = world.min(axis=0), world.max(axis=0)
    return lo + (hi - lo) * rng.random((n, 3))
