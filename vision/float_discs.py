"""The float's discs measured on the pond plane: a colour blob's outline through the tower
homography H, tested for a disc's area, roundness and rim (vision/float_detect.py uses these).

A blob is mapped to the pond plane and must have the disc's area (its outline runs through the rim
pixels' centres, so each rim pixel adds a quarter of its area, and small blobs get slack for
their pixel steps) and roundness there; a centred hole makes it a ring (a lifebuoy). A disc
partly washed over keeps the arc of its rim: its centre comes from a circle of known radius fitted
robustly to the rim points, and its confidence drops with the share hidden.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from vision.float_detect import FloatParams


@dataclass(frozen=True)
class _Disc:
    centre: np.ndarray      # pond (2,)
    conf: float


def _pond(H: np.ndarray, px: np.ndarray) -> np.ndarray:
    h = px @ H[:, :2].T + H[:, 2]
    return h[:, :2] / h[:, 2:3]


def _m2_per_px(H: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Pond area (m^2) one pixel covers at each pixel: |det J| = |det H| / |w|^3."""
    w = px @ H[2, :2] + H[2, 2]
    with np.errstate(divide="ignore"):
        return abs(np.linalg.det(H)) / np.abs(w) ** 3


def _shoelace(p: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Area, centroid and 2x2 second central moments (per unit area) of polygon ``p``."""
    o = p[0]
    q = p - o
    x, y = q[:, 0], q[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    c = x * yn - xn * y
    a = c.sum() / 2.0
    if abs(a) < 1e-12:
        return 0.0, p.mean(axis=0), np.zeros((2, 2))
    cx = ((x + xn) * c).sum() / (6 * a)
    cy = ((y + yn) * c).sum() / (6 * a)
    sxx = ((x * x + x * xn + xn * xn) * c).sum() / (12 * a) - cx * cx
    syy = ((y * y + y * yn + yn * yn) * c).sum() / (12 * a) - cy * cy
    sxy = ((x * yn + 2 * x * y + 2 * xn * yn + xn * y) * c).sum() / (24 * a) - cx * cy
    return abs(a), o + np.array([cx, cy]), np.array([[sxx, sxy], [sxy, syy]])


def _rim_fit(p: np.ndarray, c0: np.ndarray, r: float, px: float) -> tuple[np.ndarray, float]:
    """Centre of a circle of known radius ``r`` through the rim points of a partly hidden disc, and
    the share of the rim's angle seen. The edge where water covers the disc is not rim: a vote over
    centres near ``c0`` finds the circle most rim points lie on with none outside it, then least
    squares on those points."""
    tol = max(0.12 * r, 0.8 * px)
    g = np.linspace(-r, r, 21)
    cand = c0 + np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    dist = np.hypot(p[None, :, 0] - cand[:, 0:1], p[None, :, 1] - cand[:, 1:2])
    score = (np.abs(dist - r) < tol).sum(axis=1) - 2 * (dist > r + tol).sum(axis=1)
    c = cand[int(np.argmax(score))].copy()
    for _ in range(5):
        d = p - c
        dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        keep = np.abs(dist - r) < tol
        if keep.sum() < 3:
            break
        J = -d[keep] / dist[keep, None]
        step = np.linalg.lstsq(J, -(dist[keep] - r), rcond=None)[0]
        c += step
        if np.hypot(*step) < 1e-3 * r:
            break
    d = p - c
    on_rim = np.abs(np.hypot(d[:, 0], d[:, 1]) - r) < tol
    bins = np.unique(((np.arctan2(d[on_rim, 1], d[on_rim, 0]) + np.pi) / (2 * np.pi) * 24).astype(int) % 24)
    return c, len(bins) / 24.0


def _disc(H, outline: np.ndarray, holes: list[np.ndarray], m2: float, px: float, diameter: float,
          params: FloatParams) -> _Disc | None:
    """The disc a blob shows (its outline and holes in full-frame pixels), measured on the pond;
    None if it is not one: wrong size, a ring, not round, or too little of its rim seen."""
    rim = _pond(H, outline)
    if not np.all(np.isfinite(rim)):
        return None
    area_m2, centre, cov = _shoelace(rim)
    disc_area = math.pi * diameter * diameter / 4
    # the outline runs through the rim pixels' centres, inside the edge (mixed pixels count in part)
    n_rim = len(outline)
    fill = (area_m2 + 0.25 * n_rim * m2) / disc_area
    # a blob's area is known to about +-0.7 px along its rim: small blobs get that much slack
    slack = 0.7 * n_rim * m2 / disc_area
    if not params.min_fill - slack <= fill <= params.max_fill + slack:
        return None
    if holes:
        # hole outlines run through the blob's inner rim pixels: half a pixel outside the hole
        for h in holes:
            area, hc, _ = _shoelace(_pond(H, h))
            if area - 0.5 * len(h) * m2 > params.ring_hole * fill * disc_area \
                    and np.hypot(*(hc - centre)) < 0.25 * diameter:
                return None                                  # a lifebuoy: a ring
    ev = np.linalg.eigvalsh(cov)
    roundness = math.sqrt(max(ev[0], 0) / ev[1]) if ev[1] > 0 else 0.0
    step = px / (diameter / 2)                               # pixel steps bend a small blob's axes
    whole = fill >= 0.85 - slack
    if whole and roundness < params.min_roundness - step:
        return None                                          # whole-sized but not round: not a disc
    size = 1.0 if fill <= 1.15 + slack else max(0.0, 1 - (fill - 1.15 - slack) / 0.7)
    conf = size * min(1.0, roundness / max(0.9 - step, 0.5))
    if step > 0.4:                                           # too few pixels to fit a rim to
        return _Disc(centre, float(conf * min(1.0, fill))) if whole else None
    # the outline runs through rim pixels' centres, and rim pixels are those mostly covered: on the edge
    c, seen = _rim_fit(rim, centre, diameter / 2, px)
    shift = float(np.hypot(*(c - centre)))
    if whole and shift <= max(0.06 * diameter, 0.8 * px):
        return _Disc(centre, float(conf))                   # the centroid: the whole area's average
    if seen < 0.3 or shift > diameter / 2:
        return None
    return _Disc(c, float(min(1.0, fill) * min(1.0, seen / 0.6) * 0.8))


def _discs(H, mask: np.ndarray, origin: np.ndarray, scale: int, diameter: float,
           params: FloatParams) -> list[_Disc]:
    contours, hier = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return []
    hier = hier[0]
    disc_area = math.pi * diameter * diameter / 4
    lo, hi = 0.6 * params.min_fill * disc_area, 1.3 * params.max_fill * disc_area
    found = []
    for i, c in enumerate(contours):
        if hier[i][3] >= 0 or len(c) < 4:
            continue
        pts = c.reshape(-1, 2).astype(float) * scale + (scale - 1) / 2.0 + origin
        p0 = pts.mean(axis=0)
        q = _pond(H, np.array([p0, p0 + (scale, 0), p0 + (0, scale)]))
        J = (q[1:] - q[0]).T                                 # pond metres per (downscaled) pixel step
        m2 = abs(float(np.linalg.det(J)))
        # loose: holes and wash-over are judged on the pond; this only drops noise and large blobs
        a = cv2.contourArea(c)
        if not ((a + len(c)) * m2 >= lo and a * m2 <= hi):
            continue
        holes, j = [], hier[i][2]
        while j >= 0:
            holes.append(contours[j].reshape(-1, 2).astype(float) * scale + (scale - 1) / 2.0 + origin)
            j = hier[j][0]
        found.append((pts, holes, m2, float(np.linalg.norm(J, 2))))
    out = []
    for pts, holes, m2, px in found[:40]:
        d = _disc(H, pts, holes, m2, px, diameter, params)
        if d is not None:
            out.append(d)
    return out
