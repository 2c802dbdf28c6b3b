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


def water_brightness(K: np.ndarray, R: np.ndarray, image_size: tuple[int, int], level: float,
                     gradient: float, step: int = 8) -> np.ndarray:
    """(H, W) float32: radiance of the water along each pixel's ray, ``level`` looking level and
    exp(3 * gradient * sin(elevation)) times that looking up or down (world z up). Smooth, so
    computed on a coarse grid and interpolated."""
    w, h = image_size
    u, v = np.meshgrid(np.arange(0, w + step, step, dtype=float), np.arange(0, h + step, step, dtype=float))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T @ R
    e = rays[..., 2] / np.linalg.norm(rays, axis=-1)
    b = (level * np.exp(3.0 * gradient * e)).astype(np.float32)
    full = cv2.resize(b, (b.shape[1] * step, b.shape[0] * step), interpolation=cv2.INTER_LINEAR)
    return full[:h, :w]


def sun_rays(K: np.ndarray, R: np.ndarray, image_size: tuple[int, int], strength: float,
             azimuth_deg: float, seed: int, step: int = 8) -> np.ndarray:
    """(H, W) float32 gain around 1: shafts of sunlight through the water, brighter bands that
    fan out downwards. A function of each ray's world direction, so both cameras see the same
    shafts from their own viewpoints."""
    w, h = image_size
    u, v = np.meshgrid(np.arange(0, w + step, step, dtype=float), np.arange(0, h + step, step, dtype=float))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T @ R
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    az = np.arctan2(rays[..., 1], rays[..., 0]) - np.radians(azimuth_deg)
    tilt = az + 0.6 * rays[..., 2]                  # shafts lean with the sun
    rng = np.random.default_rng(seed)
    g = np.zeros_like(tilt)
    for f in rng.uniform(6, 30, 5):                 # a few shafts per radian of view
        g += np.cos(f * tilt + rng.uniform(0, 2 * np.pi))
    g = np.maximum(g / 5, 0) ** 2 * (0.6 + 0.4 * np.clip(rays[..., 2] + 0.5, 0, 1))
    out = (1.0 + strength * g / (g.max() + 1e-9)).astype(np.float32)
    full = cv2.resize(out, (out.shape[1] * step, out.shape[0] * step), interpolation=cv2.INTER_LINEAR)
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


def cage_net_texture(rng: np.random.Generator, mesh_mm: float, twine_mm: float, angle_deg: float,
                     texel_mm: float, size: int = 1024) -> np.ndarray:
    """(size, size) float32 0..1: a sea-cage net of square meshes turned by ``angle_deg`` (45: a
    diamond net), 1 on the twine, fouled unevenly."""
    r, c = np.indices((size, size), dtype=np.float32) * texel_mm
    a = np.radians(angle_deg)
    u, v = c * np.cos(a) + r * np.sin(a), -c * np.sin(a) + r * np.cos(a)
    half = twine_mm / 2
    du = np.abs((u / mesh_mm) % 1.0 - 0.5) * mesh_mm      # mm from the mesh centre, across each twine
    dv = np.abs((v / mesh_mm) % 1.0 - 0.5) * mesh_mm
    edge = np.maximum(du, dv) - (mesh_mm / 2 - half)
    net = np.clip(edge / max(texel_mm, 0.5) + 0.5, 0, 1)
    fouling = random_texture((size, size), rng, (4.0, 15.0, 40.0))
    return (net * (0.55 + 0.45 * fouling)).astype(np.float32)


def rock_texture(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size) float32 0..1: rock and weed patches with sharp edges (a reef, a cage's
    fouled frame), fine grain inside them."""
    blobs = random_texture((size, size), rng, tuple(float(s) for s in rng.uniform([3, 8, 20], [6, 16, 45])))
    cut, soft = rng.uniform(0.35, 0.65), rng.uniform(0.01, 0.06)
    patches = np.clip((blobs - cut) / soft + 0.5, 0, 1)
    grain = random_texture((size, size), rng, (1.0, 2.5))
    return (patches * (0.75 + 0.25 * grain) + (1 - patches) * 0.15 * grain).astype(np.float32)


def underwater_background(rig, cam: int, cond: dict, rng_tex: dict) -> tuple[np.ndarray, np.ndarray]:
    """(frame, veil) float32 (H, W, 3) BGR 0..255 for camera ``cam`` (0 left, 1 right)."""
    K, R = (rig.K1, rig.R1) if cam == 0 else (rig.K2, rig.R2)
    P = rig.P1 if cam == 0 else rig.P2
    bright = water_brightness(K, R, rig.image_size, cond["water_brightness"], cond["gradient"])
    if cond["sun_rays"] > 0:
        bright *= sun_rays(K, R, rig.image_size, cond["sun_rays"], cond["sun_azimuth_deg"], cond["_rays_seed"])
    bright = np.ascontiguousarray(bright, dtype=np.float32)
    veil = cv2.multiply(_bgr(bright), _scalar(cond["water_bgr"]))
    clutter = cond["clutter"]
    if clutter == "none":
        return veil.copy(), veil
    centre = np.asarray(rig.target, float)
    forward = centre - (rig.centres[0] + rig.centres[1]) / 2
    forward[2] = 0.0
    forward /= np.linalg.norm(forward)
    side = np.array([forward[1], -forward[0], 0.0])
    dist = cond["clutter_range_mm"]
    texel = {"net": 4.0, "cage": 2.0}.get(clutter, 9.0)
    tex = rng_tex[clutter]
    half = tex.shape[0] * texel / 2
    base = (rig.centres[0] + rig.centres[1]) / 2 + forward * dist
    e1, e2 = side, np.array([0.0, 0.0, -1.0])      # a net wall or a rock face behind the fish
    origin = base - half * e1 - half * e2
    img, cover = warp_plane(tex, P, origin, e1, e2, texel, rig.image_size)
    trans = np.float32(np.exp(-dist / cond["visibility_mm"]))
    if clutter == "net":
        col = cv2.multiply(veil, _scalar(np.asarray(cond["net_bgr"]) / 128.0))
        a = img * cover * trans
    elif clutter in ("rock", "cage"):      # patches or twine of their own tone, the water between
        col = cv2.multiply(veil, _scalar(cond["clutter_tone"]))
        a = img * cover * trans
    else:       # rock lit by the water's light: boulders and dark crevices
        rock = np.clip((img - 0.5) * 2.5 + 0.5, 0.0, 1.0)
        col = cv2.multiply(_bgr((0.25 + 1.5 * rock) * bright * np.float32(1.4)),
                           _scalar(np.asarray(cond["reef_bgr"]) / 255.0))
        a = cover * trans
    return cv2.blendLinear(col, veil, a, 1.0 - a), veil


def _bgr(grey: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(grey, dtype=np.float32), cv2.COLOR_GRAY2BGR)


def _scalar(bgr) -> tuple[float, float, float, float]:
    return tuple(float(v) for v in bgr) + (0.0,)


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


def surface_reflections(frame: np.ndarray, rig, cam: int, cond: dict, textures: dict) -> None:
    """Add the lamps' glitter on the rippled water surface (z = 0) to ``frame``: brightest around
    each lamp's mirror image in this camera, spread over the ripples' range of slopes, plus a faint
    sheen of the room everywhere. Ripples are frozen over a clip (drawn once per camera)."""
    key = ("_glitter", cam)
    if key not in textures:
        P = rig.P1 if cam == 0 else rig.P2
        w, h = rig.image_size
        ripples = textures["ripples"]
        texel = 2.5
        half = ripples.shape[0] * texel / 2
        rip, cover = warp_plane(ripples, P, [-half, -half, 0.0], [1.0, 0, 0], [0, 1.0, 0], texel, rig.image_size)
        step = 8
        yy, xx = np.mgrid[0:h + step:step, 0:w + step:step].astype(np.float32)
        glare = np.zeros(xx.shape, np.float32)
        for lamp in cond["lamps"]:
            px = P @ np.r_[lamp[0], lamp[1], -lamp[2], 1.0]
            if px[2] <= 0:
                continue
            u, v = px[:2] / px[2]
            glare += np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * cond["glare_px"] ** 2))
        glare = cv2.resize(glare, (glare.shape[1] * step, glare.shape[0] * step))[:h, :w]
        spec = cond["glare_strength"] * glare * (0.15 + 1.7 * rip ** 3) + cond["sheen"] * rip
        textures[key] = (spec * cover * 255.0).astype(np.float32)
    frame += textures[key][..., None]


def ripple_texture(rng: np.random.Generator, size: int = 768) -> np.ndarray:
    """(size, size) 0..1: the sparkle pattern of a gently rippled surface."""
    t = random_texture((size, size), rng, (2.0, 5.0))
    return np.clip((t - 0.45) / 0.55, 0, 1).astype(np.float32)


def sparkle_texture(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float32 0..1: sparse soft dots where a glinting scale catches the light."""
    dots = (rng.random(shape, dtype=np.float32) < 0.03).astype(np.float32)
    dots = cv2.GaussianBlur(dots, (0, 0), 0.8)
    return dots / dots.max()


def add_noise(frame: np.ndarray, sigma: float, rng: np.random.Generator, cache: dict | None = None,
              key: object = "_noise") -> np.ndarray:
    """uint8 image: ``frame`` plus Gaussian sensor noise (independent per channel), clipped and
    rounded. With ``cache`` the noise is cut at a random offset from a bank drawn once (video);
    each camera needs its own ``key``: shifted copies of one bank in the two images would give a
    stereo matcher a false match at the shift."""
    h, w = frame.shape[:2]
    bank = None if cache is None else cache.get(key)
    if bank is None:
        cv2.setRNGSeed(int(rng.integers(1 << 31)))
        bank = np.empty((h + 61, w + 67, 3), np.float32)
        cv2.randn(bank, 0.0, float(sigma))
        if cache is not None:
            cache[key] = bank
    oy, ox = int(rng.integers(0, 62)), int(rng.integers(0, 68))
    out = cv2.add(frame, bank[oy:oy + h, ox:ox + w])
    cv2.threshold(out, 0, 0, cv2.THRESH_TOZERO, dst=out)
    return cv2.convertScaleAbs(out)


def finish(frame: np.ndarray, cam: int, cond: dict, rng: np.random.Generator, cache: dict) -> np.ndarray:
    """The camera's own part: lens vignetting and this camera's gain (the two cameras of a rig
    never quite match), Gaussian sensor noise, 8 bits, and JPEG compression when the scene has a
    ``jpeg_quality`` (video and stills from real rigs are compressed)."""
    h, w = frame.shape[:2]
    key = ("_vignette", cam)
    if key not in cache:
        yy, xx = np.ogrid[:h, :w]
        cy, cx = (h - 1) / 2, (w - 1) / 2
        r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / (cx ** 2 + cy ** 2)
        v = ((1.0 - cond["vignette"] * r2) * cond["camera_gain"][cam]).astype(np.float32)
        cache[key] = cv2.merge([v, v, v])
    out = add_noise(cv2.multiply(frame, cache[key]), cond["noise_sd"], rng, cache, ("_noise", cam))
    q = cond.get("jpeg_quality")
    if q:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(q)])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out


def particle_layer(shape: tuple[int, int], px: np.ndarray, dist: np.ndarray, veil: np.ndarray,
                   visibility_mm: float) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
    """Marine snow (organic specks lit by the downwelling light, a pixel or two each) as sparse
    (rows, cols), BGR values to add: drawn once, added to each frame cheaply."""
    h, w = shape
    u, v = np.rint(px[:, 0]).astype(int), np.rint(px[:, 1]).astype(int)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h) & (dist > 0)
    layer = np.zeros((h, w), np.float32)
    np.add.at(layer, (v[ok], u[ok]), (0.25 + 0.5 * np.exp(-dist[ok] / visibility_mm)).astype(np.float32))
    layer = np.minimum(cv2.GaussianBlur(layer, (0, 0), 0.7) * np.float32(4.0), 1.0)
    idx = np.nonzero(layer > 0.02)
    return idx, layer[idx][:, None] * (veil[idx] * 0.8 + 40.0)
