"""Minimal fish drawn from the contract's words, with cv2 primitives, independent of the renderer:
a body (an ellipse from the snout back) with a forked caudal fin whose innermost fork point is
known exactly. In 2-D (detector tests) or as a flat outline in 3-D projected through a pinhole rig
(association and pipeline tests). Drawn with each pixel's area coverage, as a sensor integrates light
over a pixel (cv2.fillPoly alone fills every pixel within ~0.5 px of the outline: a fish drawn
~0.5 px too big all round and its fork's narrow end filled in)."""
from __future__ import annotations

import cv2
import numpy as np


def fish_outline(n: int = 73, notch_deg: float = 60.0, depth: float = 0.38, span: float = 0.3,
                 snout_power: float = 0.5) -> np.ndarray:
    """Outline (M, 2) of a fish of fork length 1 in its own frame: x from the fork's innermost point
    (0, 0) to the snout (1, 0), y across (dorsal +). Near the snout the outline's half depth goes as
    (1 - x)^snout_power: 0.5 the ellipse's rounded head, 1 a cone, more a pointed snout."""
    t0 = np.arccos(-0.36 / 0.44)                      # where the ellipse meets x = 0.2
    t = np.linspace(-t0, t0, n)                          # bottom-rear, over the snout (t = 0), top-rear
    sin = np.sin(t)
    body = np.c_[0.56 + 0.44 * np.cos(t), depth / 2 * np.sign(sin) * np.abs(sin) ** (2 * snout_power)]
    h = span / 2
    a = np.radians(notch_deg)
    tip = (-h / np.tan(a), h)
    top = [(0.12, 0.05), (0.07, 0.055),
           (tip[0] + 0.03, h * 1.03), tip, (0.0, 0.0)]
    bottom = [(x, -y) for x, y in reversed(top[:-1])]
    return np.vstack([bottom, body, top])


SUPER = 8        # sub-samples a pixel per side for the area coverage (edges right to 1/16 px)


def covered(shape: tuple[int, int], pts: np.ndarray) -> np.ndarray:
    """Share of each pixel of an image ``shape`` (pixel centres at integers) the polygon ``pts``
    (M, 2) covers."""
    big = np.zeros((shape[0] * SUPER, shape[1] * SUPER), np.uint8)
    q = np.rint((np.asarray(pts, float) * SUPER + (SUPER - 1) / 2) * 16).astype(np.int32)
    cv2.fillPoly(big, [q], 255, lineType=cv2.LINE_8, shift=4)
    return cv2.resize(big, (shape[1], shape[0]), interpolation=cv2.INTER_AREA).astype(np.float32) / 255


def paint(img: np.ndarray, pts: np.ndarray, value: float) -> None:
    """Paints the polygon ``pts`` (M, 2, image px) into img (float, grey or colour) in ``value``, each
    pixel blended by the share of it the polygon covers."""
    pts = np.asarray(pts, float)
    h, w = img.shape[:2]
    x0, y0 = np.maximum(np.floor(pts.min(axis=0)).astype(int) - 1, 0)
    x1, y1 = np.minimum(np.ceil(pts.max(axis=0)).astype(int) + 2, [w, h])
    if x1 <= x0 or y1 <= y0:
        return
    a = covered((y1 - y0, x1 - x0), pts - [x0, y0])
    part = img[y0:y1, x0:x1]
    if img.ndim == 3:
        a = a[:, :, None]
    mixed = part * (1 - a) + value * a
    part[...] = np.rint(mixed) if np.issubdtype(img.dtype, np.integer) else mixed


def draw_fish_2d(img: np.ndarray, fork_xy, angle: float, length_px: float, value: float, **shape) -> np.ndarray:
    """Draws a fish (filled, by area coverage) into img (float); returns its snout pixel. ``angle``:
    image direction from the fork to the snout (rad)."""
    out = fish_outline(**shape) * length_px
    c, s = np.cos(angle), np.sin(angle)
    pts = np.asarray(fork_xy, float) + out[:, :1] * [c, s] + out[:, 1:] * [-s, c]
    paint(img, pts, value)
    return np.asarray(fork_xy, float) + length_px * np.array([c, s])


def fish_scene_2d(rng, n=6, size=(720, 960), snout_power=0.5):
    """Fish of 120-280 px at any heading, dark on light water or light on dark, apart from each other,
    their snouts of ``snout_power`` (``fish_drawing.fish_outline``): (image uint8, forks (n, 2), snouts (n, 2))."""
    img = water(*size, rng, top=rng.uniform(60, 190), bottom=rng.uniform(60, 190))
    forks, snouts = [], []
    for k in range(n):
        L = rng.uniform(120, 280)
        a = rng.uniform(-np.pi, np.pi)
        centre = np.array([160 + (k % 3) * 320, 180 + (k // 3) * 360], float)
        fork = centre - 0.5 * L * np.array([np.cos(a), np.sin(a)])
        value = 30.0 if img[int(centre[1]), int(centre[0])] > 120 else 220.0
        snouts.append(draw_fish_2d(img, fork, a, L, value, snout_power=snout_power))
        forks.append(fork)
    noisy = img + rng.normal(0, 2.0, img.shape)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8), np.array(forks), np.array(snouts)


def water(h: int, w: int, rng: np.random.Generator, top: float = 190.0, bottom: float = 60.0,
          noise: float = 3.0) -> np.ndarray:
    """Grey water with a vertical illumination gradient and sensor noise (float32)."""
    col = np.linspace(top, bottom, h, dtype=np.float32)[:, None]
    return np.repeat(col, w, axis=1) + rng.normal(0, noise, (h, w)).astype(np.float32)


def fish_world(fork_mm, heading, length_mm: float, up=(0.0, 0.0, 1.0), tilt_deg: float = 0.0,
               **shape) -> tuple[np.ndarray, np.ndarray]:
    """Outline (M, 3) and snout (3,) in world mm of a flat fish in the vertical plane through its axis: fork at
    ``fork_mm``, ``heading`` a horizontal direction from the fork towards the head."""
    up = np.asarray(up, float)
    heading = np.asarray(heading, float)
    heading = heading - heading @ up * up
    heading /= np.linalg.norm(heading)
    t = np.radians(tilt_deg)
    axis = np.cos(t) * heading + np.sin(t) * up
    dorsal = -np.sin(t) * heading + np.cos(t) * up
    out = fish_outline(**shape) * length_mm
    fork_mm = np.asarray(fork_mm, float)
    return fork_mm + out[:, :1] * axis + out[:, 1:] * dorsal, fork_mm + length_mm * axis


def draw_polygon(img: np.ndarray, px: np.ndarray, value: float) -> None:
    paint(img, px, value)


def underwater_pair(rng: np.random.Generator, rig, n_fish: int = 4, lengths_mm=(200.0, 350.0),
                    ranges_mm=(700.0, 1600.0), max_tilt_deg: float = 10.0, noise: float = 3.0):
    """A grey stereo pair of flat fish swimming level (world z up) in front of ``rig``, painted far
    to near, and their truths: list of (snout_mm, fork_mm, snout_px (2, 2), fork_px (2, 2))."""
    w, h = rig.image_size
    imgs = [water(h, w, rng, noise=0.0) for _ in range(2)]
    c1, c2 = rig.centres
    mid = (c1 + c2) / 2
    fwd = rig.target - mid
    fwd /= np.linalg.norm(fwd)
    side = np.cross(fwd, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    fish = []
    for _ in range(n_fish):
        dist = rng.uniform(*ranges_mm)
        L = rng.uniform(*lengths_mm)
        centre = mid + dist * fwd + side * rng.uniform(-0.25, 0.25) * dist + [0, 0, rng.uniform(-0.15, 0.15) * dist]
        heading = np.cross([0.0, 0.0, 1.0], fwd) * rng.choice([-1, 1])
        turn = np.radians(rng.uniform(-35, 35))
        heading = np.cos(turn) * heading + np.sin(turn) * fwd
        fork = centre - 0.5 * L * heading
        outline, snout = fish_world(fork, heading, L, tilt_deg=rng.uniform(-max_tilt_deg, max_tilt_deg))
        fish.append((dist, outline, snout, fork, rng.uniform(20, 100) if rng.random() < 0.6 else rng.uniform(170, 240)))
    fish.sort(key=lambda f: -f[0])
    truths = []
    for _, outline, snout, fork, value in fish:
        for img, px in zip(imgs, rig.project(outline), strict=True):
            draw_polygon(img, px, value)
        p1, p2 = rig.project(np.array([snout, fork]))
        truths.append((snout, fork, np.array([p1[0], p2[0]]), np.array([p1[1], p2[1]])))
    out = [np.clip(im + rng.normal(0, noise, im.shape), 0, 255).astype(np.uint8) for im in imgs]
    return out[0], out[1], truths
