"""Water, background and optics of the simulated stereo camera (everything but the fish).

Underwater: the veiling light of the water itself, brighter along rays looking up (sunlight
attenuating with depth: the paper's vertical illumination gradient), optionally a net or a
reef-like rock face behind the fish, seen through the same water. Surface: a nursery tank floor
under lamps, and the lamps' mirror images on the rippled water surface. Backgrounds are world
planes warped into each camera through its own homography, so both views agree geometrically.
"""
from __future__ import annotations

import cv2
import numpy as np

from devices.sim.stereo_scene import random_texture


def ray_elevation(K: np.ndarray, R: np.ndarray, image_size: tuple[int, int], step: int = 8) -> np.ndarray:
    """(H, W) float32: sine of the elevation of each pixel's viewing ray (world z up)."""
    w, h = image_size
    u, v = np.meshgrid(np.arange(0, w + step, step, dtype=float), np.arange(0, h + step, step, dtype=float))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T @ R
    e = (rays[..., 2] / np.linalg.norm(rays, axis=-1)).astype(np.float32)
    full = cv2.resize(e, (e.shape[1] * step, e.shape[0] * step), interpolation=cv2.INTER_LINEAR)
    return full[:h, :w]


def plane_homography(P: np.ndarray, origin: np.ndarray, e1: np.ndarray, e2: np.ndarray,
                     texel_mm: float) -> np.ndarray:
    """Texel (col, row) of a texture on the plane origin + col*texel*e1 + row*texel*e2 -> pixel."""
    H = np.c_[P[:, :3] @ (texel_mm * e1), P[:, :3] @ (texel_mm * e2), P[:, :3] @ origin + P[:, 3]]
    return H / H[2, 2]


def warp_plane(texture: np.ndarray, P: np.ndarray, origin, e1, e2, texel_mm: float,
               image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(image, coverage) of a textured plane seen by camera P (bilinear; the texture mirrored
    beyond its edges, so the plane has no end in view)."""
    H = plane_homography(P, np.asarray(origin, float), np.asarray(e1, float), np.asarray(e2, float), texel_mm)
    img = cv2.warpPerspective(texture, H, image_size, flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REFLECT)
    return img, np.ones(img.shape[:2], np.float32)


def net_texture(rng: np.random.Generator, mesh_mm: float, texel_mm: float, size: int = 1024) -> np.ndarray:
    """(size, size) float32 0..1: a diamond net, 1 on the twine, a little fouling mottle."""
    r, c = np.indices((size, size), dtype=np.float32) * texel_mm
    period = mesh_mm * np.sqrt(2)
    d1 = np.abs(((r + c) / period) % 1.0 - 0.5)
    d2 = np.abs(((r - c) / period) % 1.0 - 0.5)
    twine = 1.5 / period + rng.uniform(0.0, 1.0) / period
    net = np.clip((np.maximum(d1, d2) - (0.5 - twine)) / (twine * 0.5), 0, 1)
    return (net * (0.7 + 0.3 * random_texture((size, size), rng, (6.0, 20.0)))).astype(np.float32)


def underwater_background(rig, cam: int, cond: dict, rng_tex: dict) -> tuple[np.ndarray, np.ndarray]:
    """(frame, veil) float32 (H, W, 3) BGR 0..255 for camera ``cam`` (0 left, 1 right)."""
    K, R = (rig.K1, rig.R1) if cam == 0 else (rig.K2, rig.R2)
    P = rig.P1 if cam == 0 else rig.P2
    e = ray_elevation(K, R, rig.image_size)
    bright = cond["water_brightness"] * np.exp(cond["gradient"] * 3.0 * e)
    veil = np.asarray(cond["water_bgr"], np.float32)[None, None, :] * bright[..., None]
    frame = veil.copy()
    clutter = cond["clutter"]
    if clutter in ("net", "reef"):
        centre = np.asarray(rig.target, float)
        forward = centre - (rig.centres[0] + rig.centres[1]) / 2
        forward[2] = 0.0
        forward /= np.linalg.norm(forward)
        side = np.array([forward[1], -forward[0], 0.0])
        dist = cond["clutter_range_mm"]
        texel = 4.0 if clutter == "net" else 6.0
        tex = rng_tex[clutter]
        half = tex.shape[0] * texel / 2
        base = (rig.centres[0] + rig.centres[1]) / 2 + forward * dist
        e1, e2 = side, np.array([0.0, 0.0, -1.0])      # a net wall or a rock face behind the fish
        origin = base - half * e1 - half * e2
        img, cover = warp_plane(tex, P, origin, e1, e2, texel, rig.image_size)
        trans = float(np.exp(-dist / cond["visibility_mm"]))
        if clutter == "net":
            col = veil * (np.asarray(cond["net_bgr"], np.float32) / 128.0)
            a = (img * cover * trans)[..., None]
            frame = frame + (col - frame) * a
        else:
            col = veil * (np.asarray(cond["reef_bgr"], np.float32) / 128.0) * (0.4 + 0.9 * img[..., None])
            a = (cover * trans)[..., None]
            frame = frame + (col - frame) * a
    return frame.astype(np.float32), veil.astype(np.float32)


def surface_background(rig, cam: int, cond: dict, rng_tex: dict) -> tuple[np.ndarray, np.ndarray]:
    """(frame, veil) float32 (H, W, 3): the tank floor under the lamps, through clear water."""
    P = rig.P1 if cam == 0 else rig.P2
    tex = rng_tex["floor"]
    texel = 3.0
    half = tex.shape[0] * texel / 2
    floor_z = -cond["floor_depth_mm"]
    origin = np.array([-half, -half, floor_z])
    img, cover = warp_plane(tex, P, origin, [1.0, 0, 0], [0, 1.0, 0], texel, rig.image_size)
    floor = np.asarray(cond["floor_bgr"], np.float32)[None, None, :] * (0.75 + 0.5 * img[..., None])
    lit = lamp_irradiance(rig, cam, cond, floor_z)
    veil = np.asarray(cond["water_bgr"], np.float32)[None, None, :] * np.ones_like(lit)[..., None]
    frame = floor * lit[..., None] * cover[..., None] + veil * (1 - cover[..., None])
    return frame.astype(np.float32), veil.astype(np.float32)


def _plane_points(rig, cam: int, z: float, step: int = 16) -> tuple[np.ndarray, tuple[int, int]]:
    """World points (h, w, 3) where a coarse grid of pixels' rays meet the plane at height z."""
    K, R, t = (rig.K1, rig.R1, rig.t1) if cam == 0 else (rig.K2, rig.R2, rig.t2)
    w, h = rig.image_size
    u, v = np.meshgrid(np.arange(0, w + step, step, dtype=float), np.arange(0, h + step, step, dtype=float))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T @ R
    c = -R.T @ t
    s = (z - c[2]) / np.where(np.abs(rays[..., 2]) < 1e-9, 1e-9, rays[..., 2])
    return c + rays * s[..., None], (w, h)


def lamp_irradiance(rig, cam: int, cond: dict, z: float) -> np.ndarray:
    """(H, W) float32 relative irradiance of the plane at height z from the scene's lamps."""
    pts, (w, h) = _plane_points(rig, cam, z)
    total = np.zeros(pts.shape[:2])
    for lamp in cond["lamps"]:
        d = np.asarray(lamp, float) - pts
        r2 = np.einsum("...i,...i->...", d, d)
        total += d[..., 2] / np.sqrt(r2) / r2
    total /= total.max() + 1e-12
    full = cv2.resize(total.astype(np.float32), (total.shape[1] * 16, total.shape[0] * 16))
    return (0.35 + 0.65 * full[:h, :w]).astype(np.float32)


def surface_reflections(frame: np.ndarray, rig, cam: int, cond: dict, ripples: np.ndarray) -> None:
    """Add the lamps' specular images on the rippled water surface (z = 0) to ``frame``."""
    P = rig.P1 if cam == 0 else rig.P2
    w, h = rig.image_size
    texel = 1.5
    half = ripples.shape[0] * texel / 2
    rip, cover = warp_plane(ripples, P, [-half, -half, 0.0], [1.0, 0, 0], [0, 1.0, 0], texel, rig.image_size)
    glare = np.zeros((h, w), np.float32)
    for lamp in cond["lamps"]:
        mirror = np.array([lamp[0], lamp[1], -lamp[2]], float)
        px = P @ np.r_[mirror, 1.0]
        if px[2] <= 0:
            continue
        u, v = px[:2] / px[2]
        yy, xx = np.ogrid[:h, :w]
        spread = cond["glare_px"]
        glare += np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * spread ** 2)).astype(np.float32)
    spec = cond["glare_strength"] * glare * (0.3 + 1.4 * rip ** 3) * cover
    spec += cond["sheen"] * rip * cover
    frame += spec[..., None] * 255.0


def ripple_texture(rng: np.random.Generator, size: int = 768) -> np.ndarray:
    """(size, size) 0..1: the sparkle pattern of a gently rippled surface."""
    t = random_texture((size, size), rng, (2.0, 5.0))
    return np.clip((t - 0.45) / 0.55, 0, 1).astype(np.float32)


def add_noise(frame: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """uint8 image: ``frame`` plus Gaussian sensor noise, clipped and quantised."""
    noise = rng.standard_normal(frame.shape[:2], dtype=np.float32) * np.float32(sigma)
    out = frame + noise[..., None]
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)
