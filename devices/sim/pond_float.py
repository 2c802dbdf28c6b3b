"""Painting things that lie on the water into a frame: the float marker, wash-over, occluders.

Every shape is a polygon on the pond plane (or above it) projected through the tower camera's
exact projection, its vertices placed to 1/64 pixel and its coverage sampled 4 x 4 times a pixel,
so a disc is the true perspective ellipse, antialiased and no larger than it is.
Shading and blending happen only inside the shape's bounding box: a float costs a few hundred
pixels of work, not a frame.
"""
from __future__ import annotations

import math

import cv2
import numpy as np
import shapely

from devices.sim.pond_camera import BLUE_DIAMETER_M, ORANGE_DIAMETER_M, FloatPose, TowerView

SHIFT = 4                       # fillPoly sub-pixel bits
SUPER = 4                       # samples per pixel side for antialiased coverage
DISC_POINTS = 96
OCCLUDERS = ("boat", "spray", "bird")


def circle(cx: float, cy: float, r: float, n: int = DISC_POINTS) -> np.ndarray:
    a = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    return np.stack([cx + r * np.cos(a), cy + r * np.sin(a)], -1)


def hsv_bgr(h: float, s: float, v: float) -> np.ndarray:
    """OpenCV HSV (h 0..180, s, v 0..1) -> BGR float 0..255."""
    px = np.array([[[h, s * 255, v * 255]]], np.float32)
    return cv2.cvtColor(np.clip(px, 0, 255).astype(np.uint8), cv2.COLOR_HSV2BGR)[0, 0].astype(np.float32)


class Roi:
    """A clipped bounding box of pixels with their pond coordinates, for painting shapes."""

    def __init__(self, view: TowerView, pts_px: np.ndarray, pad: int = 3):
        self.view = view
        lo = np.floor(pts_px.min(axis=0)).astype(int) - pad
        hi = np.ceil(pts_px.max(axis=0)).astype(int) + pad + 1
        self.x0, self.y0 = max(lo[0], 0), max(lo[1], 0)
        self.x1, self.y1 = min(hi[0], view.width), min(hi[1], view.height)
        self._xy = None

    @property
    def empty(self) -> bool:
        return self.x1 <= self.x0 or self.y1 <= self.y0

    @property
    def shape(self) -> tuple[int, int]:
        return self.y1 - self.y0, self.x1 - self.x0

    def of(self, img: np.ndarray) -> np.ndarray:
        return img[self.y0:self.y1, self.x0:self.x1]

    @property
    def xy(self) -> np.ndarray:
        """(h, w, 2) pond coordinates of the box's pixel centres."""
        if self._xy is None:
            u, v = np.meshgrid(np.arange(self.x0, self.x1, dtype=float), np.arange(self.y0, self.y1, dtype=float))
            self._xy = self.view.to_pond(np.stack([u.ravel(), v.ravel()], -1)).reshape(*u.shape, 2)
        return self._xy

    def mask(self, polys_px: list[np.ndarray]) -> np.ndarray:
        """(h, w) float32 0..1 coverage of the polygons (pixel coordinates): filled at SUPER x
        SUPER samples a pixel and averaged, so edges are antialiased without growing the shape."""
        h, w = self.shape
        m = np.zeros((h * SUPER, w * SUPER), np.uint8)
        pts = [np.round(((p - [self.x0, self.y0]) * SUPER + (SUPER - 1) / 2) * (1 << SHIFT)).astype(np.int32)
               for p in polys_px]
        cv2.fillPoly(m, pts, 255, cv2.LINE_8, shift=SHIFT)
        return cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255


def blend(roi_img: np.ndarray, colour: np.ndarray, alpha: np.ndarray) -> None:
    """roi_img <- roi_img (1 - alpha) + colour alpha, in place (colour (3,) or (h, w, 3))."""
    a = alpha[..., None]
    roi_img[:] = np.clip(roi_img * (1 - a) + colour * a, 0, 255).astype(np.uint8)


def disc_colour(xy: np.ndarray, c: tuple[float, float], r: float, bgr: np.ndarray, look: dict) -> np.ndarray:
    """(h, w, 3) shaded colour of a domed disc: lit from the sun's side, darker to the rim."""
    rel = (xy - np.asarray(c)) / r
    sun = np.array([math.cos(look["sun_az"]), math.sin(look["sun_az"])])
    rho2 = np.minimum(np.sum(rel * rel, -1), 1.0)
    shade = (1 + look["shade"] * (rel @ sun)) * (1 - 0.25 * rho2 ** 2)
    return (bgr * look["light"]) * shade[..., None].astype(np.float32)


def draw_float(frame: np.ndarray, view: TowerView, pose: FloatPose, look: dict, t_s: float,
               washover: float = 0.0) -> None:
    """Paint the orange and blue discs (contract sizes, blue 0.40 m ahead) into ``frame``; in the
    sun's glitter path the glare veils them and a highlight flickers on the orange dome."""
    bx, by = pose.blue_xy()
    if np.any(view.depth(np.array([[pose.x_m, pose.y_m, 0.0], [bx, by, 0.0]])) <= 1.0):
        return                                   # under or behind the camera: not in its view
    orange = view.to_pixels(circle(pose.x_m, pose.y_m, ORANGE_DIAMETER_M / 2))
    blue = view.to_pixels(circle(bx, by, BLUE_DIAMETER_M / 2, DISC_POINTS // 2))
    roi = Roi(view, np.vstack([orange, blue]))
    if roi.empty:
        return
    img = roi.of(frame)
    water = img.astype(np.float32)
    glare = look["glare_at"](pose.x_m, pose.y_m)
    veil = np.float32(255 * 0.35 * glare)
    sunlit = look["sun_at"](pose.x_m, pose.y_m, t_s)           # under a cloud's shadow or not
    for poly, c, r, bgr in ((orange, (pose.x_m, pose.y_m), ORANGE_DIAMETER_M / 2, look["orange"]),
                            (blue, (bx, by), BLUE_DIAMETER_M / 2, look["blue"])):
        colour = disc_colour(roi.xy, c, r, bgr, look) * (sunlit * (1 - 0.35 * glare)) + veil
        blend(img, colour * look["vignette"](roi), roi.mask([poly]))
    if glare > 0.05:
        sun = np.array([math.cos(look["sun_az"]), math.sin(look["sun_az"])])
        spot = view.to_pixels(circle(*(np.array([pose.x_m, pose.y_m]) + 0.07 * sun), 0.045, 24))
        flicker = 0.5 + 0.5 * math.sin(9.0 * t_s + 3 * pose.x_m)
        blend(img, np.float32(255), roi.mask([spot]) * min(1.0, 2 * glare) * flicker)
    if washover > 0:
        _wash(img, water, roi, pose, washover, t_s)


def _wash(img: np.ndarray, water: np.ndarray, roi: Roi, pose: FloatPose, amount: float, t_s: float) -> None:
    """A wave's crest running over the float: a band of water, up to ``amount`` opaque, crossing it
    every few seconds from a direction that turns slowly."""
    d_ang = 0.7 * t_s / 7.0 + 1.0
    d = np.array([math.cos(d_ang), math.sin(d_ang)])
    period = 3.5
    front = -0.8 + 1.6 * ((t_s % period) / period)
    s = (roi.xy - [pose.x_m, pose.y_m]) @ d
    a = amount * 0.9 * np.exp(-((s - front) / 0.12) ** 2)
    crest = amount * 0.5 * np.exp(-((s - front - 0.08) / 0.03) ** 2)     # broken water at the crest
    blend(img, water, a.astype(np.float32))
    blend(img, np.float32(215), crest.astype(np.float32))


def _outlines() -> dict[str, np.ndarray]:
    """Each occluder's outline in its own frame: (across the motion, along it), metres."""
    a = np.linspace(-1, 1, 25)
    boat = np.concatenate([np.stack([1.6 * a, 0.6 * np.sqrt(1 - a ** 8)], -1),       # its long side
                           np.stack([-1.6 * a, -0.6 * np.sqrt(1 - a ** 8)], -1)])    # sweeps the float
    # a gull close under the camera, so it looks far larger than it would on the water
    bird = np.array([[0.0, 0.6], [0.25, 0.5], [0.42, 0.4], [0.9, 0.42], [1.4, 0.3], [1.3, 0.18],
                     [0.8, 0.0], [0.45, -0.35], [0.3, -0.7], [0.0, -0.6], [-0.3, -0.7], [-0.45, -0.35],
                     [-0.8, 0.0], [-1.3, 0.18], [-1.4, 0.3], [-0.9, 0.42], [-0.42, 0.4], [-0.25, 0.5]])
    b = np.linspace(0, 2 * math.pi, 40, endpoint=False)
    r = 0.75 + 0.12 * np.sin(5 * b) + 0.08 * np.cos(9 * b)
    return {"boat": boat, "bird": bird, "spray": np.stack([r * np.sin(b), r * np.cos(b)], -1)}


OUTLINES = _outlines()


def occluder_shape(kind: str, centre: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Polygon (pond m) of an occluder centred at ``centre``, moving along unit ``d``."""
    half = OUTLINES[kind]
    return centre + half[:, :1] * np.array([-d[1], d[0]]) + half[:, 1:2] * d


def float_samples(pose: FloatPose, spacing_m: float = 0.01) -> np.ndarray:
    """Points on a square grid over the two discs (pond m), to measure how much area is hidden."""
    bx, by = pose.blue_xy()
    g = np.arange(-0.5, 0.5 + spacing_m / 2, spacing_m)
    u, v = np.meshgrid(g, g)
    xy = np.c_[u.ravel(), v.ravel()] + [pose.x_m, pose.y_m]
    keep = (np.hypot(xy[:, 0] - pose.x_m, xy[:, 1] - pose.y_m) <= ORANGE_DIAMETER_M / 2) | \
        (np.hypot(xy[:, 0] - bx, xy[:, 1] - by) <= BLUE_DIAMETER_M / 2)
    return xy[keep]


def place_occluder(kind: str, pose: FloatPose, fraction: float, d: np.ndarray) -> np.ndarray:
    """The occluder's polygon slid along ``d`` until it covers ``fraction`` of the float's area."""
    pts = float_samples(pose)
    mid = pts.mean(axis=0)

    def covered(offset: float) -> float:
        poly = shapely.Polygon(occluder_shape(kind, mid + offset * d, d))
        return float(np.mean(shapely.contains_xy(poly, pts[:, 0], pts[:, 1])))

    lo, hi = -3.0, 0.0                         # far before the float .. centred on it
    if fraction >= 1.0 or covered(hi) <= fraction:
        return occluder_shape(kind, mid, d)
    for _ in range(30):
        m = (lo + hi) / 2
        lo, hi = (m, hi) if covered(m) < fraction else (lo, m)
    return occluder_shape(kind, mid + hi * d, d)


def draw_occluder(frame: np.ndarray, view: TowerView, pose: FloatPose, fraction: float, kind: str,
                  d_ang: float, look: dict) -> None:
    """Hide ``fraction`` of the float under a boat, a bird or spray coming from ``d_ang``."""
    d = np.array([math.cos(d_ang), math.sin(d_ang)])
    poly = place_occluder(kind, pose, fraction, d)
    if np.any(view.depth(np.c_[poly, np.zeros(len(poly))]) <= 1.0):
        return
    px = view.to_pixels(poly)
    roi = Roi(view, px)
    if roi.empty:
        return
    img = roi.of(frame)
    m = roi.mask([px])
    light = look["light"]
    if kind == "boat":
        inner = view.to_pixels(poly.mean(axis=0) + 0.8 * (poly - poly.mean(axis=0)))
        blend(img, np.array([225.0, 228, 230]) * light, m)
        blend(img, np.array([95.0, 105, 110]) * light, roi.mask([inner]))
    elif kind == "bird":
        span = np.abs((roi.xy - poly.mean(axis=0)) @ np.array([-d[1], d[0]]))
        tone = 215 - 150 * np.clip((span - 0.9) / 0.4, 0, 1)              # dark wing tips
        blend(img, np.repeat(tone[..., None], 3, -1) * light, m)
    else:
        rng = np.random.default_rng(int(abs(d_ang) * 1e6) % (2 ** 32))
        tex = cv2.GaussianBlur(rng.uniform(0.8, 1.05, roi.shape).astype(np.float32), (0, 0), 1.5)
        soft = np.minimum(m, cv2.GaussianBlur(m, (0, 0), 2.0) * 1.6)        # thin spray at the edge
        blend(img, (np.array([240.0, 240, 236]) * light) * tex[..., None], np.clip(soft, 0, 1))
