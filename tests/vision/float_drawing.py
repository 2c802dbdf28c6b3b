"""The cleaner's float seen from a tower, drawn from the contract's words with cv2 primitives,
independently of the detector and of the pond renderer: an orange disc 0.40 m across centred on
the robot, a blue disc 0.20 m across 0.40 m ahead along the heading, both flat on the water and
drawn through a pinhole camera's exact plane-to-image map (so they are ellipses), over a noisy
green-brown water texture, with optional distractors, sun glints and a wash-over edge."""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

ORANGE = (0, 110, 250)       # BGR
BLUE = (190, 80, 20)
WATER = (70, 95, 80)
SHIFT = 4                    # fixed-point bits of cv2's sub-pixel drawing


@dataclass(frozen=True)
class View:
    width: int
    height: int
    G: np.ndarray            # pond (x, y, 1) -> pixel (u, v, 1)

    @property
    def H(self) -> np.ndarray:
        H = np.linalg.inv(self.G)
        return H / H[2, 2]

    def pixels(self, xy: np.ndarray) -> np.ndarray:
        h = np.c_[xy, np.ones(len(xy))] @ self.G.T
        return h[:, :2] / h[:, 2:3]


def view(width=1280, height=720, pond=(20.0, 10.0), tower=(10.0, -6.0, 9.0), hfov_deg=70.0) -> View:
    """A camera at ``tower`` (x, y, z) looking at the pond's centre, x of the image to the right."""
    eye = np.array(tower, dtype=float)
    target = np.array([pond[0] / 2, pond[1] / 2, 0.0])
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])                 # world -> camera rows
    t = -R @ eye
    f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    G = K @ np.c_[R[:, 0], R[:, 1], t]
    return View(width, height, G / G[2, 2])


@lru_cache(maxsize=4)
def _grain(width: int, height: int, noise: float) -> np.ndarray:
    """Sensor noise for frames of this size, drawn once; each frame takes a window of it."""
    return np.random.default_rng(99).normal(0, noise, (height + 32, width + 32, 3)).astype(np.int16)


def water(v: View, seed=0, noise=6.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ripple = cv2.resize(rng.normal(0, 12, (v.height // 16 + 1, v.width // 16 + 1)).astype(np.float32),
                        (v.width, v.height), interpolation=cv2.INTER_CUBIC).astype(np.int16)
    dx, dy = rng.integers(0, 32, 2)
    img = _grain(v.width, v.height, noise)[dy:dy + v.height, dx:dx + v.width] + ripple[:, :, None]
    img += np.array(WATER, np.int16)
    return np.clip(img, 0, 255).astype(np.uint8)


def disc(img, v: View, centre, diameter, colour, inner=0.0) -> None:
    a = np.linspace(0, 2 * np.pi, 96, endpoint=False)
    ring = np.c_[np.cos(a), np.sin(a)]
    outer = np.round(v.pixels(np.asarray(centre) + ring * diameter / 2) * (1 << SHIFT)).astype(np.int32)
    cv2.fillPoly(img, [outer], colour, cv2.LINE_AA, SHIFT)
    if inner > 0:
        hole = np.round(v.pixels(np.asarray(centre) + ring * inner / 2) * (1 << SHIFT)).astype(np.int32)
        cv2.fillPoly(img, [hole], WATER, cv2.LINE_AA, SHIFT)


def float_marker(img, v: View, x, y, heading) -> None:
    disc(img, v, (x, y), 0.40, ORANGE)
    disc(img, v, (x + 0.40 * np.cos(heading), y + 0.40 * np.sin(heading)), 0.20, BLUE)


def cover(img, v: View, x, y, normal, offset, colour=WATER) -> None:
    """Water over the pond half-plane {p : (p - (x, y)) . normal > offset} near the float."""
    n = np.array([np.cos(normal), np.sin(normal)])
    t = np.array([-n[1], n[0]])
    c = np.array([x, y]) + n * offset
    poly = np.array([c + t, c + t + n, c - t + n, c - t])
    cv2.fillPoly(img, [np.round(v.pixels(poly) * (1 << SHIFT)).astype(np.int32)], colour, cv2.LINE_AA, SHIFT)


def glint(img, v: View, x, y, size=0.15) -> None:
    disc(img, v, (x, y), size, (250, 250, 255))


def frame(v: View, pose, *, seed=0, distractors=True, wash=None) -> np.ndarray:
    """One frame: the float at pose (x, y, heading) or none; distractors around the pond."""
    img = water(v, seed)
    if distractors:
        disc(img, v, (3.0, 7.5), 0.55, ORANGE)              # an orange buoy, no blue partner
        disc(img, v, (16.0, 8.0), 0.40, ORANGE)             # a buoy the float's size, alone
        disc(img, v, (6.0, 2.0), 0.70, ORANGE, inner=0.42)   # a lifebuoy
        disc(img, v, (14.0, 2.5), 0.30, BLUE)               # a blue object
        disc(img, v, (9.0, 8.5), 0.20, BLUE)                # a blue ball the blue disc's size
        for gx, gy in ((4.0, 4.0), (12.0, 6.0), (17.0, 3.0), (8.0, 1.0)):
            glint(img, v, gx, gy)
    if pose is not None:
        float_marker(img, v, *pose)
        if wash is not None:
            cover(img, v, pose[0], pose[1], *wash)
    return img
