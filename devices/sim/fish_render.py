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


def project(rig, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``rig.project`` for any number of points (OpenCV's wants its points as (N, 1, 3))."""
    world = np.asarray(world, dtype=float).reshape(-1, 3)
    out = []
    for K, D, R, t in ((rig.K1, rig.D1, rig.R1, rig.t1), (rig.K2, rig.D2, rig.R2, rig.t2)):
        if len(world) == 0:
            out.append(np.zeros((0, 2)))
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
    albedo: np.ndarray             # (N, 3) BGR
    fin_albedo: np.ndarray         # (3,) BGR
    glint: np.ndarray              # (M,) specular strength per body face (scales catch light)
    fin_alpha: float               # fin opacity 0..1


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


def face_colours(p: Posed, cam_centre: np.ndarray, light: Light) -> tuple[np.ndarray, np.ndarray]:
    """(visible face mask (M,), BGR colour (M, 3) of each body face) seen from ``cam_centre``."""
    a, b, c = (p.verts[p.body[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    centroid = (a + b + c) / 3
    view = cam_centre - centroid
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    visible = np.einsum("ij,ij->i", n, view) > 0
    diffuse = np.clip(n @ light.direction, 0, None)
    depth_light = light.at(centroid[:, 2])
    h = view + light.direction
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    spec = np.clip(np.einsum("ij,ij->i", n, h), 0, None) ** light.shininess * p.glint
    albedo = p.albedo[p.body].mean(axis=1)
    colour = albedo * (light.ambient + (1 - light.ambient) * diffuse)[:, None] * light.colour
    colour = (colour + spec[:, None]) * depth_light[:, None]
    return visible, colour


def _fill_groups(img: np.ndarray, tri: np.ndarray, colours: np.ndarray, levels: int = 48) -> None:
    """Fill triangles (n, 3, 2) fixed-point int32 into ``img`` in groups of equal quantised colour."""
    q = np.clip(np.rint(colours * (levels / 255.0)), 0, 2 * levels).astype(np.int64)
    key = (q[:, 0] * 256 + q[:, 1]) * 256 + q[:, 2]
    order = np.argsort(key, kind="stable")
    keys, starts = np.unique(key[order], return_index=True)
    bounds = np.r_[starts, len(order)]
    for g in range(len(keys)):
        sel = order[bounds[g]:bounds[g + 1]]
        col = tuple(float(v) for v in q[sel[0]] * (255.0 / levels))
        cv2.fillPoly(img, list(tri[sel]), col, lineType=cv2.LINE_8, shift=SHIFT)


@dataclass
class Drawn:
    """What drawing one fish in one camera left: its mask size in the frame."""

    pixels: int                    # mask pixels inside the frame (body and fins)
    inside: bool                   # every vertex projects inside the frame


def draw_fish(frame: np.ndarray, ranks: np.ndarray, rank: int, p: Posed, px: np.ndarray,
              cam_centre: np.ndarray, light: Light, veil: np.ndarray, visibility_mm: float,
              blur_px: float) -> Drawn:
    """Draw fish ``p`` whose vertices project to ``px`` (N, 2) into ``frame`` (H, W, 3 float32)."""
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
    visible, colours = face_colours(p, cam_centre, light)
    colour = np.zeros((ph, pw, 3), np.float32)
    body = np.zeros((ph, pw), np.uint8)
    fin = np.zeros((ph, pw), np.uint8)
    fin_tri = fixed[p.fins]
    cv2.fillPoly(fin, list(fin_tri), 255, lineType=cv2.LINE_8, shift=SHIFT)
    fin_col = p.fin_albedo * light.colour * (light.ambient + 0.5 * (1 - light.ambient))
    fin_col *= light.at(p.verts[:, 2].mean())
    colour[fin > 0] = fin_col
    body_tri = fixed[p.body[visible]]
    cv2.fillPoly(body, list(body_tri), 255, lineType=cv2.LINE_8, shift=SHIFT)
    _fill_groups(colour, body_tri, colours[visible])
    alpha = np.maximum(body.astype(np.float32) / 255, (fin > 0) * np.float32(p.fin_alpha))
    rng_mm = float(np.linalg.norm(p.verts.mean(axis=0) - cam_centre))
    trans = np.float32(np.exp(-rng_mm / visibility_mm))
    sl = np.s_[cy0:cy1, cx0:cx1]
    colour = colour * trans + veil[sl] * (1 - trans)
    sigma = max(blur_px, 0.45)                      # a soft edge even in focus (anti-aliasing)
    alpha = cv2.GaussianBlur(alpha, (0, 0), sigma)
    if blur_px > 0.5:
        colour = cv2.GaussianBlur(colour, (0, 0), blur_px)
    frame[sl] += (colour - frame[sl]) * alpha[..., None]
    covered = (body > 0) | (fin > 0)
    ranks[sl][covered] = rank
    return Drawn(int(covered.sum()), inside)


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
    yy, xx = np.mgrid[cy0:cy1, cx0:cx1].astype(np.float32)
    d = np.hypot(xx - centre[0], yy - centre[1])
    a = np.clip(r + 0.5 - d, 0, 1) * alpha
    rim = np.clip(1 - np.abs(d - r * 0.7) / max(r * 0.5, 0.7), 0, 1)       # bright rim, clearer core
    shade = (0.55 + 0.45 * rim)[..., None]
    frame[cy0:cy1, cx0:cx1] += (colour * shade - frame[cy0:cy1, cx0:cx1]) * a[..., None]
    if ranks is not None:
        ranks[cy0:cy1, cx0:cx1][a > 0.5] = rank
