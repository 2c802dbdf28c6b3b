"""Things in and around the pond that look a little like the float: the detector's traps.

Floating (drawn every frame, drifting on their moorings): orange buoys (spheres 0.3-0.5 m),
lifebuoys (rings 0.6-0.8 m across, orange or red and white), blue objects (balls, a tarp). On
the bank across the water from the tower: orange posts and lifebuoys on stands, drawn with their
mirror images in the water (the point (x, y, -z) seen through the same camera), dimmed and
wobbling with the ripples: orange in the pond that is nowhere near the float.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import shapely

from devices.sim.pond_camera import TowerView
from devices.sim.pond_float import Roi, blend, circle, hsv_bgr

SUN_EL = math.radians(50)
KINDS = ("buoy", "lifebuoy", "blue", "bank")


@dataclass(frozen=True)
class Thing:
    kind: str            # buoy, lifebuoy, lifebuoy_rw, ball, tarp, post, stand
    xy: tuple[float, float]
    size_m: float        # diameter (buoy, ring, ball), height (post, stand), width (tarp)
    bgr: np.ndarray
    phase: float         # mooring drift phase
    shape: np.ndarray | None = None   # tarp outline relative to xy


def _inside_points(outline: np.ndarray, n: int, rng: np.random.Generator, inset: float) -> list[np.ndarray]:
    poly = shapely.Polygon(outline)
    inner = poly.buffer(-inset)
    inner = inner if not inner.is_empty else poly
    lo, hi = np.asarray(inner.bounds[:2]), np.asarray(inner.bounds[2:])
    out: list[np.ndarray] = []
    while len(out) < n:
        p = rng.uniform(lo, hi)
        if inner.contains(shapely.Point(p)):
            out.append(p)
    return out


def _far_bank_points(outline: np.ndarray, view: TowerView, n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Points 0.7 m outside the pond's edges that face away from the tower (their reflections
    fall on the water in front of them)."""
    eye = view.centre_m[:2]
    ring = np.vstack([outline, outline[:1]])
    area2 = np.sum(outline[:, 0] * np.roll(outline[:, 1], -1) - np.roll(outline[:, 0], -1) * outline[:, 1])
    cands = []
    for a, b in zip(ring[:-1], ring[1:], strict=True):
        d = b - a
        normal = np.array([d[1], -d[0]]) / (np.hypot(*d) + 1e-12) * (1 if area2 > 0 else -1)  # outward
        for f in np.linspace(0.1, 0.9, 9):
            p = a + f * d
            if np.dot(normal, p - eye) > 0:
                cands.append(p + 0.7 * normal)
    if not cands:
        return []
    idx = rng.choice(len(cands), size=min(n, len(cands)), replace=False)
    return [cands[i] for i in idx]


def make_things(outline: np.ndarray, view: TowerView, count: int, rng: np.random.Generator) -> list[Thing]:
    """``count`` distractors, every kind represented once there are four or more."""
    if count <= 0:
        return []
    kinds = [KINDS[i % len(KINDS)] for i in range(count)] if count >= 4 else list(rng.choice(KINDS[:3], count))
    things: list[Thing] = []
    spots = iter(_inside_points(outline, count, rng, 0.8))
    bank = iter(_far_bank_points(outline, view, kinds.count("bank"), rng))
    for kind in kinds:
        ph = float(rng.uniform(0, 2 * math.pi))
        orange = hsv_bgr(rng.uniform(3, 20), rng.uniform(0.7, 1.0), rng.uniform(0.75, 1.0))
        if kind == "buoy":
            things.append(Thing("buoy", tuple(next(spots)), float(rng.uniform(0.3, 0.5)), orange, ph))
        elif kind == "lifebuoy":
            rw = rng.random() < 0.5
            bgr = hsv_bgr(rng.uniform(174, 180), 0.9, 0.85) if rw else orange
            things.append(Thing("lifebuoy_rw" if rw else "lifebuoy", tuple(next(spots)),
                                float(rng.uniform(0.6, 0.8)), bgr, ph))
        elif kind == "blue":
            blue = hsv_bgr(rng.uniform(98, 118), rng.uniform(0.6, 0.95), rng.uniform(0.5, 0.9))
            p = next(spots)
            if rng.random() < 0.5:
                things.append(Thing("ball", tuple(p), float(rng.uniform(0.18, 0.35)), blue, ph))
            else:
                a = np.sort(rng.uniform(0, 2 * math.pi, 7))
                r = rng.uniform(0.2, 0.45, 7)
                things.append(Thing("tarp", tuple(p), 0.8, blue, ph, np.c_[r * np.cos(a), r * np.sin(a)]))
        else:
            p = next(bank, None)
            if p is not None:
                things.append(Thing("post" if rng.random() < 0.5 else "stand", tuple(p),
                                    float(rng.uniform(0.8, 1.4)), orange, ph))
    return _pair_a_blue_with_a_buoy(things, outline, rng)


def _pair_a_blue_with_a_buoy(things: list[Thing], outline: np.ndarray, rng: np.random.Generator) -> list[Thing]:
    """Moor the first blue thing 0.7-1.0 m from the first buoy: an orange and a blue blob at about
    the float's spacing, but not its sizes or spacing, for the detector's pairing to refuse."""
    buoy = next((t for t in things if t.kind == "buoy"), None)
    blue = next((i for i, t in enumerate(things) if t.kind in ("ball", "tarp")), None)
    if buoy is None or blue is None:
        return things
    a = rng.uniform(0, 2 * math.pi)
    xy = np.asarray(buoy.xy) + rng.uniform(0.7, 1.0) * np.array([math.cos(a), math.sin(a)])
    if shapely.Polygon(outline).buffer(-0.5).contains(shapely.Point(xy)):
        t = things[blue]
        things[blue] = Thing(t.kind, (float(xy[0]), float(xy[1])), t.size_m, t.bgr, buoy.phase, t.shape)
    return things


def _sphere_colour(roi: Roi, c, r: float, bgr: np.ndarray, look: dict) -> np.ndarray:
    rel = (roi.xy - np.asarray(c)) / r
    nz = np.sqrt(np.clip(1 - np.sum(rel * rel, -1), 0, 1))
    sun = np.array([math.cos(look["sun_az"]) * math.cos(SUN_EL), math.sin(look["sun_az"]) * math.cos(SUN_EL),
                    math.sin(SUN_EL)])
    lit = np.clip(rel[..., 0] * sun[0] + rel[..., 1] * sun[1] + nz * sun[2], 0, 1)
    col = bgr * (0.35 + 0.75 * lit)[..., None] * look["light"]
    spec = np.clip((lit - 0.93) * 14, 0, 1)[..., None]
    return col * (1 - spec) + 255 * spec


def drift(thing: Thing, t_s: float) -> np.ndarray:
    """A floating thing's centre: swinging slowly round its mooring (bank things stand still)."""
    if thing.kind in ("post", "stand"):
        return np.asarray(thing.xy)
    w = 2 * math.pi / 23.0
    swing = np.array([math.sin(w * t_s + thing.phase), math.cos(0.7 * w * t_s + thing.phase)])
    return np.asarray(thing.xy) + 0.15 * swing


class Floating:
    """The floating distractors, each painted once at its mooring into a sprite (premultiplied
    colour and coverage, found by painting it over black and over white) and pasted every frame
    where its drift has taken it, to the nearest pixel."""

    def __init__(self, view: TowerView, things: list[Thing], look: dict):
        self.view = view
        self.sun_at = look["sun_at"]
        self.sprites = []
        for th in things:
            if th.kind in ("post", "stand"):
                continue
            c = np.asarray(th.xy, float)
            px = view.to_pixels(c + th.shape) if th.kind == "tarp" else view.to_pixels(circle(*c, th.size_m / 2, 64))
            roi = Roi(view, px)
            if roi.empty:
                continue
            over = []
            for ground in (0, 255):
                img = np.full((*roi.shape, 3), ground, np.uint8)
                _paint(img, roi, view, th, c, look, px)
                over.append(img.astype(np.float32))
            alpha = 1 - (over[1] - over[0]).mean(-1, keepdims=True) / 255
            self.sprites.append((th, view.to_pixels(c)[0], roi.x0, roi.y0, over[0], alpha))

    def draw(self, frame: np.ndarray, t_s: float) -> None:
        h, w = frame.shape[:2]
        for th, anchor_px, x0, y0, premult, alpha in self.sprites:
            now = drift(th, t_s)
            dx, dy = np.round(self.view.to_pixels(now)[0] - anchor_px).astype(int)
            sh, sw = alpha.shape[:2]
            ax, ay = x0 + dx, y0 + dy
            cx0, cy0, cx1, cy1 = max(ax, 0), max(ay, 0), min(ax + sw, w), min(ay + sh, h)
            if cx1 <= cx0 or cy1 <= cy0:
                continue
            sub = (slice(cy0 - ay, cy1 - ay), slice(cx0 - ax, cx1 - ax))
            img = frame[cy0:cy1, cx0:cx1]
            sun = np.float32(self.sun_at(now[0], now[1], t_s))
            img[:] = np.clip(img * (1 - alpha[sub]) + premult[sub] * sun, 0, 255).astype(np.uint8)


def _paint(img: np.ndarray, roi: Roi, view: TowerView, th: Thing, c: np.ndarray, look: dict, px: np.ndarray) -> None:
    vign = look["vignette"](roi)
    if th.kind in ("buoy", "ball"):
        blend(img, _sphere_colour(roi, c, th.size_m / 2, th.bgr, look) * vign, roi.mask([px]))
    elif th.kind == "tarp":
        blend(img, th.bgr * look["light"] * vign, roi.mask([px]))
    else:
        _ring(img, roi, view, th, c, look, vign)


def _ring(img, roi: Roi, view: TowerView, th: Thing, c, look: dict, vign) -> None:
    r_out, r_in = th.size_m / 2, th.size_m / 2 * 0.6
    shade = 0.85 + 0.3 * np.cos(np.hypot(*(roi.xy - c).transpose(2, 0, 1)) / r_out * math.pi - 0.8 * math.pi)
    col = th.bgr * look["light"] * shade[..., None] * vign
    if th.kind == "lifebuoy":
        outer, inner = view.to_pixels(circle(*c, r_out, 64)), view.to_pixels(circle(*c, r_in, 64))
        blend(img, col, np.clip(roi.mask([outer]) - roi.mask([inner]), 0, 1))
        return
    white = np.array([235.0, 235, 235]) * look["light"] * shade[..., None] * vign
    for k in range(8):                                   # red and white quarters, twice round
        a = np.linspace(k * math.pi / 4, (k + 1) * math.pi / 4, 12) + 0.4
        sector = np.r_[np.c_[np.cos(a), np.sin(a)] * r_out, np.c_[np.cos(a[::-1]), np.sin(a[::-1])] * r_in] + c
        blend(img, col if k % 2 == 0 else white, roi.mask([view.to_pixels(sector)]))


def bank_polygons(th: Thing, view: TowerView, mirrored: bool) -> list[np.ndarray]:
    """Pixel polygons of a bank object (a post, or a lifebuoy hanging on a stand) or of its mirror
    image in the water (z -> -z)."""
    s = -1.0 if mirrored else 1.0
    x, y = th.xy
    eye = view.centre_m
    side = np.array([-(y - eye[1]), x - eye[0]])
    side /= np.hypot(*side) + 1e-12

    def post(top: float, half_w: float) -> np.ndarray:          # seen face on
        w = half_w * side
        return view.project(np.array([[x - w[0], y - w[1], 0], [x + w[0], y + w[1], 0],
                                      [x + w[0], y + w[1], s * top], [x - w[0], y - w[1], s * top]]))
    if th.kind == "post":
        return [post(th.size_m, 0.075)]
    a = np.linspace(0, 2 * math.pi, 48, endpoint=False)   # a ring hanging upright on a grey pole
    rings = [view.project(np.c_[x + r * np.cos(a) * side[0], y + r * np.cos(a) * side[1],
                                s * (th.size_m + r * np.sin(a))]) for r in (0.35, 0.21)]
    return [*rings, post(th.size_m - 0.3, 0.03)]


def draw_bank(base: np.ndarray, view: TowerView, things: list[Thing], look: dict, water: np.ndarray) -> None:
    """Paint the bank objects and their rippled mirror images in the water into the still picture."""
    for th in things:
        if th.kind not in ("post", "stand"):
            continue
        for mirrored in (True, False):
            polys = bank_polygons(th, view, mirrored)
            roi = Roi(view, np.vstack(polys), pad=6)
            if roi.empty:
                continue
            m = roi.mask(polys[:1])
            pole = None
            if th.kind == "stand":
                m = np.clip(m - roi.mask(polys[1:2]), 0, 1)
                pole = roi.mask(polys[2:])
            col = th.bgr * look["light"] * look["vignette"](roi)
            if mirrored:      # dimmer, broken up by ripples, streaked downwards, only on the water
                h, w = m.shape
                v, u = np.mgrid[0:h, 0:w].astype(np.float32)
                wob = u + 1.5 * np.sin(v * 0.9 + th.phase) + 0.8 * np.sin(v * 2.3)
                m = cv2.remap(m, wob, v, cv2.INTER_LINEAR)
                m = cv2.GaussianBlur(m, (0, 0), sigmaX=0.6, sigmaY=1.5) * roi.of(water) * 0.6
                col = col * 0.75
            if pole is not None:
                blend(roi.of(base), np.array([120.0, 122, 125]) * look["light"], pole * (0.5 if mirrored else 1.0))
            blend(roi.of(base), col, m.astype(np.float32))
