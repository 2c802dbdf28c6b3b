"""The still part of the pond seen from the tower: bank, rim, water colour, sky and its reflection.

Computed once per scene from each pixel's ray (where it meets the water plane, at what angle):
the bank's grass and the pond's concrete rim outside the outline, the water's own colour and
mottle inside it, darker over drains, mixed with the sky's reflection by the Fresnel factor
(stronger towards the far bank, where rays graze the water), clouds in that reflection, the sun's
glare veil over its glitter path, haze far off and the sky above the horizon.
"""
from __future__ import annotations

import cv2
import numpy as np
import shapely

from devices.sim.pond_camera import TowerView
from devices.sim.stereo_scene import random_texture

RIM_M = 0.35                 # the concrete edge around the pond
TEXEL_M = 0.04               # pond-plane texture resolution near the pond
SKY_BGR = np.array([235.0, 215.0, 190.0], np.float32)


def pixel_rays(view: TowerView, step: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pond xy (h, w, 2), hits the water (h, w) bool, cos of incidence (h, w)) for every
    ``step``-th pixel centre (OpenCV convention), on a grid of ceil(size / step)."""
    w, h = -(-view.width // step), -(-view.height // step)
    u = (np.arange(w, dtype=np.float32) * step + (step - 1) / 2)[None, :]
    v = (np.arange(h, dtype=np.float32) * step + (step - 1) / 2)[:, None]
    M = (np.linalg.inv(view.K).T @ view.R).astype(np.float32)     # ray = (u, v, 1) @ M, world frame
    rx, ry, rz = (u * M[0, i] + v * M[1, i] + M[2, i] for i in range(3))
    hits = rz < -1e-9
    eye = view.centre_m
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(hits, np.float32(-eye[2]) / rz, np.float32(np.nan))
    xy = np.stack([eye[0] + rx * s, eye[1] + ry * s], -1).astype(np.float32)
    cos_i = -rz / np.sqrt(rx * rx + ry * ry + rz * rz)
    return xy, hits, np.clip(cos_i, 0.0, 1.0).astype(np.float32)


def polygon_mask(view: TowerView, xy, shape: tuple[int, int] | None = None, aa: bool = True) -> np.ndarray:
    """(h, w) uint8 0..255 coverage of a pond polygon (straight edges stay straight in the image)."""
    mask = np.zeros(shape or (view.height, view.width), np.uint8)
    px = view.to_pixels(np.asarray(xy, float))
    cv2.fillPoly(mask, [np.round(px * 16).astype(np.int32)], 255, cv2.LINE_AA if aa else cv2.LINE_8, shift=4)
    return mask


def _sample(tex: np.ndarray, xy: np.ndarray, origin: np.ndarray, texel: float) -> np.ndarray:
    """Texture (pond plane, ``texel`` m, origin at its pixel 0) at pond points, mirrored beyond it."""
    mx = ((xy[..., 0] - origin[0]) / texel).astype(np.float32)
    my = ((xy[..., 1] - origin[1]) / texel).astype(np.float32)
    return cv2.remap(tex, np.nan_to_num(mx), np.nan_to_num(my), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def static_layer(view: TowerView, outline: np.ndarray, keepouts, cond: dict, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(base BGR float32 (h, w, 3) without vignetting, water coverage float32 0..1, vignette gain)."""
    xy, hits, cos_i = pixel_rays(view)
    lo, hi = outline.min(axis=0) - 12.0, outline.max(axis=0) + 12.0
    # texels no finer than the frame can show: about two per pixel across the pond and its bank
    n = np.minimum(np.ceil((hi - lo) / TEXEL_M).astype(int), min(1024, 2 * max(view.width, view.height)))
    texel = float(max((hi - lo)[0] / n[0], (hi - lo)[1] / n[1]))
    shape = (int(n[1]), int(n[0]))
    coarse = _sample(random_texture(shape, rng, _texels((0.12, 0.48, 1.6), texel)), xy, lo, texel)
    fine = _sample(random_texture(shape, rng, _texels((0.03, 0.08), texel)), xy, lo, texel)
    water = polygon_mask(view, outline).astype(np.float32) / 255
    rim = polygon_mask(view, _buffered(outline, RIM_M)).astype(np.float32) / 255
    body = np.asarray(cond["water_bgr"], np.float32) * (0.8 + 0.3 * coarse + 0.1 * fine)[..., None]
    for ko in keepouts:                                      # drains and feeders: deeper, darker water
        m = cv2.GaussianBlur(polygon_mask(view, ko).astype(np.float32) / 255, (0, 0), 3)
        body *= (1 - 0.35 * m)[..., None]
    clouds = _sample(random_texture((256, 256), rng, (6.0, 20.0)), xy * 0.35, lo * 0.35, texel * 8)
    fres = 0.02 + 0.98 * (1 - cos_i) ** 5
    fres = np.clip(fres * (1.0 + 1.2 * clouds), 0, 1)[..., None]
    sky = SKY_BGR * cond["light"]
    water_px = (1 - fres) * body * cond["light"] + fres * sky
    veil = np.nan_to_num(glitter_zone(xy, view, cond)) * cond["glare"] * 110
    water_px += veil[..., None] * np.array([1.0, 1.0, 0.97], np.float32)
    grass = np.array(cond["bank_bgr"], np.float32) * (0.6 + 0.5 * coarse + 0.35 * fine)[..., None]
    concrete = np.float32(150 + 40 * fine[..., None] - 20 * coarse[..., None]) * np.array([1.0, 1.0, 0.97], np.float32)
    land = grass * cond["light"]
    land = land * (1 - rim[..., None]) + concrete * cond["light"] * rim[..., None]
    img = land * (1 - water[..., None]) + water_px * water[..., None]
    far = np.nan_to_num(np.linalg.norm(xy - view.centre_m[:2].astype(np.float32), axis=-1), nan=1e4)
    haze = np.clip((far - 40) / 200, 0, 1)
    img = img * (1 - haze[..., None]) + sky * haze[..., None]
    img[~hits] = sky * (0.9 + 0.1 * fine[~hits, None])
    return img.astype(np.float32), water * hits, vignette(view.width, view.height, cond["vignette"])


def _texels(scales_m: tuple[float, ...], texel: float) -> tuple[float, ...]:
    return tuple(max(0.5, m / texel) for m in scales_m)


def vignette(w: int, h: int, strength: float) -> np.ndarray:
    """(h, w) float32 gain: cos^4-like fall-off to ``1 - strength`` in the corners."""
    u = (np.arange(w, dtype=np.float32) - (w - 1) / 2) / ((w - 1) / 2)
    v = (np.arange(h, dtype=np.float32) - (h - 1) / 2) / ((h - 1) / 2)
    r2 = (u[None, :] ** 2 + v[:, None] ** 2) / 2
    return (1 - strength * r2).astype(np.float32)


def _buffered(outline: np.ndarray, d: float) -> np.ndarray:
    poly = shapely.Polygon(outline).buffer(d, join_style="mitre", mitre_limit=3.0)
    return np.asarray(poly.exterior.coords)[:-1]


def glitter_zone(xy: np.ndarray, view: TowerView, cond: dict) -> np.ndarray:
    """0..1 weight of the sun's glitter path: around ``glare_xy``, stretched along the line from
    the tower's foot (the sun's reflection streaks towards the camera)."""
    strength = cond["glare"]
    if strength <= 0:
        return np.zeros(xy.shape[:-1], np.float32)
    c = np.asarray(cond["glare_xy"], np.float32)
    d = c - view.centre_m[:2].astype(np.float32)
    d = d / np.float32(np.linalg.norm(d) + 1e-9)
    rel = xy - c
    along = rel @ d
    across = rel @ np.array([-d[1], d[0]], np.float32)
    z = (along / (2.0 + 4.0 * strength)) ** 2 + (across / (0.6 + 1.2 * strength)) ** 2
    return (strength * np.exp(-z)).astype(np.float32)
