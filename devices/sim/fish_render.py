"""Rasterising posed fish meshes into one camera's image (painter's algorithm, far fish first).

Each fish is drawn into a patch around its projection: front-facing body triangles (back faces
culled with the 3-D normal against the ray to this camera's centre), filled by OpenCV in groups of
equal quantised colour; fins (two-sided, semi-transparent) under the body. The patch is then
seen through the water (blended towards the veiling light by exp(-range / visibility)), blurred
out of focus, and laid over the frame with a soft edge. A rank image records which drawn object
covers each pixel, from which occlusion and the truth flags are read.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

SHIFT = 3                          # fixed-point bits for sub-pixel polygon vertices
_ONE = 1 << SHIFT
# OpenCV fills every pixel whose centre lies within ~0.5 px of a polygon (an edge at x = 10.25
# fills pixel 10): each drawn fish is ~0.5 px too big all round and the caudal notch's narrow end
# is filled in, so a rendered fish read ~+1 % long at 100 px, +2 % at 50 px, against its own
# truth. A sensor integrates light over each pixel: with COVERAGE > 1 the fish's opacity is its
# area coverage, drawn at COVERAGE x resolution and averaged (left over: ~0.2 px an edge at 4,
# ~0.1 at 8; 4 costs ~+18 % of a still's CPU), and the blur applied to the fish as seen (colour x
# coverage), as optics do. 1: OpenCV's fill (the renderer before 2026-12-02; bench/diag_length_bias.py
# --coverage compares).
COVERAGE = 4
# The fill at COVERAGE x still overshoots by half a sub-pixel along the edge's major axis (0.5 x
# max(|cos|, |sin|) sub-pixels: 0.09-0.125 px an edge at 4; a rendered 40-80 px fish read +0.24 px
# long of it). The mean of the fill and the fill eroded by a 3x3 cross (which takes back
# max(|cos|, |sin|) sub-pixels) has each edge where it is at every angle (within ~0.005 px at 4;
# tests/devices/sim/test_fish_coverage.py), for +2-3 % of a 1280x960 scene's CPU. Left as it is: the
# fill rounds vertices to whole sub-pixels, so every fish sits 1/16 px down and right of its truth,
# alike in both views and at both ends (no length, no disparity). False: the renderer before
# 2026-12-07 (bench/diag_length_bias.py --no-exact-edges compares).
EXACT_EDGES = True
_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def project(rig, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``rig.project`` for any number of points (OpenCV's wants its points as (N, 1, 3))."""
    world = np.asarray(world, dtype=float).reshape(-1, 3)
    out = []
    for K, D, R, t in ((rig.K1, rig.D1, rig.R1, rig.t1), (rig.K2, rig.D2, rig.R2, rig.t2)):
        if len(world) == 0:
            out.append(np.zeros((0, 2)))
            continue
        if D is None or not np.any(D):            # pinhole: the same numbers, without OpenCV's overhead
            cam = world @ (K @ R).T + K @ np.asarray(t, float)
            out.append(cam[:, :2] / cam[:, 2:3])
            continue
        dist = np.zeros(5) if D is None else np.asarray(D, dtype=float)
        px = cv2.projectPoints(world.reshape(-1, 1, 3), cv2.Rodrigues(np.asarray(R, float))[0],
                               np.asarray(t, dtype=float), K, dist)[0]
        out.append(px.reshape(-1, 2))
    return out[0], out[1]


@dataclass
class Posed:
    """A fish ready to draw: world vertices, faces and per-vertex albedo (BGR 0..1)."""

    verts: np.ndarray              # (N, 3) world mm
    body: np.ndarray               # (M, 3) outward-wound body faces
    fins: np.ndarray               # (K, 3) fin faces (two-sided)
    albedo: np.ndarray             # (M, 3) BGR per body face
    fin_albedo: np.ndarray         # (3,) BGR
    glint: np.ndarray              # (M,) specular strength per body face (scales catch light)
    fin_alpha: float               # fin opacity 0..1
    fork_vertex: int               # index of the fork notch vertex
    gain: float = 1.0              # this fish's brightness (silvery fish flash, dark ones absorb)
    scales: float = 30.0           # scale rows along the body (diamond lattice)
    scale_contrast: float = 0.08
    surface: tuple | None = None   # per-face normals, centroids, lit colour, light (set on first use)
    fin_rays: float = 30.0         # rays across the fins per fork length
    ray_contrast: float = 0.1


@dataclass
class Light:
    direction: np.ndarray          # (3,) unit, towards the light
    colour: np.ndarray             # (3,) BGR irradiance scale
    ambient: float                 # share of diffuse light from all around
    attenuation_mm: float          # light falls as exp((z - z_ref) / attenuation) with depth
    z_ref: float = 0.0             # height where the light is ``colour`` (the rig's working depth)
    shininess: float = 30.0

    def at(self, z):
        """Relative irradiance at height z (mm): sunlight attenuating with depth."""
        return np.exp(np.minimum((np.minimum(z, 0.0) - self.z_ref) / self.attenuation_mm, 1.0))


def _bgr(grey: np.ndarray) -> np.ndarray:
    """A float32 single-channel map repeated on three channels (OpenCV does it faster than a
    numpy broadcast in the multiply or add that follows)."""
    return cv2.cvtColor(np.ascontiguousarray(grey, dtype=np.float32), cv2.COLOR_GRAY2BGR)


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / (np.sqrt(np.einsum("ij,ij->i", v, v))[:, None] + 1e-12)


def _surface(p: Posed, light: Light) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(normals, centroids, lit colour, light level) of the body faces: the same for both cameras,
    so worked out once per fish and frame."""
    if p.surface is None:
        a, b, c = (p.verts[p.body[:, k]] for k in range(3))
        e1, e2 = b - a, c - a
        n = np.stack([e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1], e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2],
                      e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]], axis=1)
        n = _unit_rows(n)
        centroid = (a + b + c) * (1 / 3)
        level = light.at(centroid[:, 2]) * p.gain
        diffuse = np.maximum(n @ light.direction, 0.0)
        colour = p.albedo * ((light.ambient + (1 - light.ambient) * diffuse) * level)[:, None] * light.colour
        p.surface = (n, centroid, colour, level)
    return p.surface


def face_colours(p: Posed, cam_centre: np.ndarray, light: Light) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(visible (M,), diffuse BGR (M, 3), specular (M,)) of each body face seen from ``cam_centre``."""
    n, centroid, colour, level = _surface(p, light)
    view = _unit_rows(cam_centre - centroid)
    visible = np.einsum("ij,ij->i", n, view) > 0
    h = _unit_rows(view + light.direction)
    spec = np.maximum(np.einsum("ij,ij->i", n, h), 0.0) ** light.shininess * p.glint * level
    return visible, colour, spec


def _fill_groups(img: np.ndarray, tri: np.ndarray, values: np.ndarray, levels: int = 20, floor: int = 1) -> None:
    """Fill triangles (n, 3, 2) fixed-point int32 into ``img`` in groups of equal quantised value
    (``values`` (n, channels) in 0..255-ish; one fillPoly call per group, not per triangle).
    With ``floor`` 1 every filled value is at least one step above 0, so ``img > 0`` is the area."""
    q = np.clip(np.rint(values * (levels / 255.0)), floor, 4 * levels).astype(np.int64)
    key = np.zeros(len(q), np.int64)
    for k in range(q.shape[1]):
        key = key * 256 + q[:, k]
    order = np.argsort(key, kind="stable")
    key, q, tri = key[order], q[order], tri[order]
    starts = np.flatnonzero(np.diff(key)) + 1
    bounds = np.concatenate([[0], starts, [len(key)]])
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        col = tuple(float(v) for v in q[a] * (255.0 / levels))
        cv2.fillPoly(img, tri[a:b], col, lineType=cv2.LINE_8, shift=SHIFT)


@dataclass
class Drawn:
    """What drawing one fish in one camera left: its mask size in the frame."""

    pixels: int                    # mask pixels inside the frame (body and fins)
    inside: bool                   # every vertex projects inside the frame


def _wave(shape, origin, snout, fork, k_along: float, k_across: float) -> np.ndarray:
    """cos(2 pi (k_along * a + k_across * b)) over the patch, a and b the position along and
    across the snout->fork axis in fork lengths; built from 1-D factors (cos(x + y) =
    cos x cos y - sin x sin y), not a cosine per pixel."""
    ax = np.asarray(fork, float) - np.asarray(snout, float)
    n2 = float(ax @ ax) + 1e-6
    gx = 2 * np.pi * (k_along * ax[0] - k_across * ax[1]) / n2      # phase per pixel along x
    gy = 2 * np.pi * (k_along * ax[1] + k_across * ax[0]) / n2
    x = (np.arange(shape[1]) + origin[0] - snout[0]) * gx
    y = (np.arange(shape[0]) + origin[1] - snout[1]) * gy
    cx, sx = np.cos(x).astype(np.float32), np.sin(x).astype(np.float32)
    cy, sy = np.cos(y).astype(np.float32), np.sin(y).astype(np.float32)
    return np.outer(cy, cx) - np.outer(sy, sx)


def _body_shading(shape: tuple[int, int], tri: np.ndarray, colours: np.ndarray, spec: np.ndarray,
                  length_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(colour (h, w, 3), body mask (h, w) uint8 255, glint (h, w) or None) of the visible body
    triangles ``tri`` (fixed point). The flat facets are smoothed by normalised convolution inside
    the body, so the outline stays sharp; a big fish's shading is worked out at half resolution
    (it is smooth) while its outline is drawn at full resolution."""
    ph, pw = shape
    q = 2 if length_px > 240 else 1
    sh = ((ph + q - 1) // q, (pw + q - 1) // q)
    tq = tri if q == 1 else tri // q
    colour = np.zeros(sh + (3,), np.float32)
    if len(tq):     # small fish: coarser shading steps (smoothed over afterwards anyway)
        _fill_groups(colour, tq, colours, levels=int(np.clip(length_px / 12, 8, 20)))
    inside = (colour[..., 0] > 0).astype(np.float32)
    k = 2 * int(np.clip(length_px / (45.0 * q), 1, 5)) + 1
    colour = cv2.stackBlur(colour, (k, k)) / np.maximum(cv2.stackBlur(inside, (k, k)), np.float32(1e-3))[..., None]
    lit = spec > 2.0
    glint = None
    if lit.any():
        glint = np.zeros(sh, np.float32)
        _fill_groups(glint, tq[lit], spec[lit][:, None], levels=12, floor=0)
    if q == 1:
        return colour, (inside > 0).view(np.uint8) * np.uint8(255), glint
    full = (sh[1] * q, sh[0] * q)
    colour = cv2.resize(colour, full, interpolation=cv2.INTER_LINEAR)[:ph, :pw]
    if glint is not None:
        glint = cv2.resize(glint, full, interpolation=cv2.INTER_NEAREST)[:ph, :pw]
    body = np.zeros((ph, pw), np.uint8)
    cv2.fillPoly(body, tri, 255, lineType=cv2.LINE_8, shift=SHIFT)
    return colour, body, glint


def draw_fish(frame: np.ndarray, ranks: np.ndarray, rank: int, p: Posed, px: np.ndarray,
              cam_centre: np.ndarray, light: Light, veil: np.ndarray, visibility_mm: float,
              blur_px: float, sparkle: np.ndarray) -> Drawn:
    """Draw fish ``p`` whose vertices project to ``px`` (N, 2) into ``frame`` (H, W, 3 float32).
    ``sparkle`` (H, W) 0..1: where a glinting scale face shows a highlight (scales are small
    mirrors: a glint is a few pixels, not a whole mesh facet)."""
    h, w = frame.shape[:2]
    inside = bool(np.all((px[:, 0] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)))
    pad = int(np.ceil(3 * blur_px)) + 3
    x0, y0 = np.floor(px.min(axis=0)).astype(int) - pad
    x1, y1 = np.ceil(px.max(axis=0)).astype(int) + pad
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if cx0 >= cx1 or cy0 >= cy1:
        return Drawn(0, inside)
    pw, ph = cx1 - cx0, cy1 - cy0
    fixed = np.rint((px - [cx0, cy0]) * _ONE).astype(np.int32)
    visible, colours, spec = face_colours(p, cam_centre, light)
    fin = np.zeros((ph, pw), np.uint8)
    cv2.fillPoly(fin, fixed[p.fins], 255, lineType=cv2.LINE_8, shift=SHIFT)
    snout_px, fork_px = px[0], px[p.fork_vertex]
    length_px = float(np.linalg.norm(fork_px - snout_px))
    colour, body, glint = _body_shading((ph, pw), fixed[p.body[visible]], colours[visible], spec[visible],
                                        length_px)
    bodyf = body.astype(np.float32) * np.float32(1 / 255)
    # a diamond lattice of scales fixed to the body (``p.scales`` rows along the fish)
    origin = (cx0, cy0)
    lattice = (_wave((ph, pw), origin, snout_px, fork_px, 2 * p.scales, 0.0)
               + _wave((ph, pw), origin, snout_px, fork_px, 0.0, 2 * p.scales))
    colour = cv2.multiply(colour, _bgr(1.0 + np.float32(0.5 * p.scale_contrast) * lattice))
    if glint is not None:
        colour = cv2.add(colour, _bgr(glint * sparkle[cy0:cy1, cx0:cx1]))
    fin_col = (p.fin_albedo * light.colour * (light.ambient + 0.5 * (1 - light.ambient))
               * light.at(p.verts[:, 2].mean()) * p.gain).astype(np.float32)
    is_fin = (fin > 0) & (body == 0)
    if is_fin.any():
        rays = 1.0 + p.ray_contrast * _wave((ph, pw), origin, snout_px, fork_px, 0.0, p.fin_rays)[is_fin]
        colour[is_fin] = fin_col * rays[:, None]
    alpha = np.maximum(bodyf, is_fin * np.float32(p.fin_alpha))
    if COVERAGE > 1:
        body_c = _coverage((ph, pw), fixed[p.body[visible]], COVERAGE)
        alpha = body_c + (1 - body_c) * _coverage((ph, pw), fixed[p.fins], COVERAGE) * np.float32(p.fin_alpha)
    rng_mm = float(np.linalg.norm(p.verts.mean(axis=0) - cam_centre))
    trans = float(np.exp(-rng_mm / visibility_mm))
    sl = np.s_[cy0:cy1, cx0:cx1]
    colour = cv2.addWeighted(colour, trans, veil[sl], 1.0 - trans, 0.0)
    if COVERAGE > 1:
        # the optics blur the fish as seen (colour x coverage), not its opacity alone: outside
        # the masks ``colour`` is black, which the blurred opacity would spread into the water
        sigma = max(blur_px, 0.45)
        seen = cv2.GaussianBlur(colour * alpha[..., None], (0, 0), sigma)
        alpha = cv2.GaussianBlur(alpha, (0, 0), sigma)
        frame[sl] = seen + frame[sl] * (1.0 - alpha)[..., None]
    else:
        alpha = cv2.GaussianBlur(alpha, (0, 0), max(blur_px, 0.45))    # a soft edge even in focus
        if blur_px > 0.5:
            colour = cv2.GaussianBlur(colour, (0, 0), blur_px)
        frame[sl] = cv2.blendLinear(colour, frame[sl], alpha, 1.0 - alpha)
    covered = (body > 0) | (fin > 0)
    ranks[sl][covered] = rank
    return Drawn(int(np.count_nonzero(covered)), inside)


def _coverage(shape: tuple[int, int], tri: np.ndarray, s: int) -> np.ndarray:
    """Share (0..1 float32) of each pixel the triangles (fixed point) cover, from a fill at ``s`` x
    resolution (sub-pixel centres: x_s = s x + (s - 1) / 2) averaged back. With ``EXACT_EDGES`` the
    fill's overshoot is taken back (module comment above ``EXACT_EDGES``)."""
    big = np.zeros((shape[0] * s, shape[1] * s), np.uint8)
    value = 127 if EXACT_EDGES else 255         # the fill and its erosion summed: 254 inside
    cv2.fillPoly(big, tri * s + _ONE * (s - 1) // 2, value, lineType=cv2.LINE_8, shift=SHIFT)
    if EXACT_EDGES:
        big = cv2.add(big, cv2.erode(big, _CROSS))
    inside = np.float32(2 * value if EXACT_EDGES else value)
    return cv2.resize(big, (shape[1], shape[0]), interpolation=cv2.INTER_AREA).astype(np.float32) / inside


SHADE_Q = 4                        # shades are soft: drawn at a quarter of the resolution


def add_shade(shade_map: np.ndarray, px: np.ndarray, strength: float, soft_px: float) -> None:
    """Add to ``shade_map`` (H/4, W/4) the soft convex outline of points ``px`` (full-res pixels):
    a fish's shade in the water under it, or its shadow on the tank floor."""
    h, w = shade_map.shape
    hull = cv2.convexHull(px.astype(np.float32)).reshape(-1, 2) / SHADE_Q
    soft = max(soft_px / SHADE_Q, 0.5)
    pad = int(3 * soft) + 2
    x0, y0 = np.floor(hull.min(axis=0)).astype(int) - pad
    x1, y1 = np.ceil(hull.max(axis=0)).astype(int) + pad
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if cx0 >= cx1 or cy0 >= cy1:
        return
    small = np.zeros((y1 - y0, x1 - x0), np.float32)
    pts = np.rint((hull - [x0, y0]) * _ONE).astype(np.int32)
    cv2.fillPoly(small, [pts], float(strength), lineType=cv2.LINE_8, shift=SHIFT)
    small = cv2.GaussianBlur(small, (0, 0), soft)
    shade_map[cy0:cy1, cx0:cx1] += small[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0]


def shaded(background: np.ndarray, shade_map: np.ndarray) -> np.ndarray:
    """A new frame: ``background`` darkened by the accumulated shades (at least 0.2 of the light
    left), in one pass (the copy every frame needs anyway)."""
    h, w = background.shape[:2]
    keep = cv2.resize(1.0 - np.minimum(shade_map, 0.8), (shade_map.shape[1] * SHADE_Q, shade_map.shape[0] * SHADE_Q),
                      interpolation=cv2.INTER_LINEAR)[:h, :w]
    return cv2.multiply(background, _bgr(keep))


def draw_disc(frame: np.ndarray, ranks: np.ndarray | None, rank: int, centre: np.ndarray, radius: float,
              colour: np.ndarray, alpha: float) -> None:
    """A soft bright disc (a bubble or a glint) at sub-pixel ``centre``."""
    h, w = frame.shape[:2]
    r = max(radius, 0.6)
    pad = int(np.ceil(r)) + 2
    x0, y0 = int(np.floor(centre[0])) - pad, int(np.floor(centre[1])) - pad
    x1, y1 = x0 + 2 * pad + 1, y0 + 2 * pad + 1
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if cx0 >= cx1 or cy0 >= cy1:
        return
    yy, xx = np.ogrid[cy0:cy1, cx0:cx1]
    d = np.hypot(xx - centre[0], yy - centre[1]).astype(np.float32)
    a = np.clip(r + 0.5 - d, 0, 1) * alpha
    rim = np.clip(1 - np.abs(d - r * 0.7) / max(r * 0.5, 0.7), 0, 1)       # bright rim, clearer core
    shade = (0.55 + 0.45 * rim)[..., None]
    frame[cy0:cy1, cx0:cx1] += (colour * shade - frame[cy0:cy1, cx0:cx1]) * a[..., None]
    if ranks is not None:
        ranks[cy0:cy1, cx0:cx1][a > 0.5] = rank
