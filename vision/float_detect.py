"""The cleaner's float seen from the tower: an orange disc 0.40 m across over the robot and a blue
disc 0.20 m across 0.40 m ahead of it (DESIGN.md, the float marker). ``detect_float`` gives the
robot's pond position (the orange centre), its heading (orange -> blue) and a confidence in 0..1.

Colour finds candidates (HSV thresholds from ``FloatParams``); every other test is done in pond
metres through the tower homography H, since perspective makes the discs ellipses of a size that
depends on where they float. A blob is mapped to the pond plane (its contour through H) and must
have a disc's area and roundness there; a ring (a lifebuoy: a hole in the middle) is refused;
what is left is paired orange with blue at the known spacing. Sun glints (white, not orange),
orange buoys (no blue partner, other size), blue objects (no orange partner) and reflections
(smeared, wrong shape) fall out of those tests. A disc partly washed over keeps the arc of its
rim: its centre comes from a circle of known radius fitted robustly to the rim, and the fix's
confidence drops with the share hidden. An orange disc touching another orange thing (the float
over a lifebuoy) is one blob no disc test passes: when a blue disc has no orange partner, the
orange disc is looked for where it must be — on the circle of the spacing round the blue one,
the place whose disc is most orange, centred on its orange (``anchored_fill``), at half the
confidence.

Nothing assumes a frame size, rate or exact colour: the whole-frame pass works on a copy
downscaled so the blue disc stays a few pixels across wherever it can be on this H, then the pair
it finds is measured again at full resolution in a small window. ``near=(x, y, r)`` (the
tracker's prediction) searches that window of the pond first.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from vision.float_blue import blue_bearing

# more of the frame (of a window round the float) than this in a marker's colour: it is the water's
# colour (the marker, a buoy beside it and glints stay far below, even in a window a metre wide)
WATER_SHARE_FRAME, WATER_SHARE_WINDOW = 0.15, 0.5


@dataclass(frozen=True)
class FloatParams:
    """The marker and the tolerances of its detection; config ``[cleaning.float]`` may set any."""
    orange_hsv: tuple[tuple[int, int, int], tuple[int, int, int]] = ((4, 110, 40), (25, 255, 255))
    blue_hsv: tuple[tuple[int, int, int], tuple[int, int, int]] = ((92, 100, 30), (132, 255, 255))
    orange_diameter_m: float = 0.40
    blue_diameter_m: float = 0.20
    spacing_m: float = 0.40
    spacing_tol_m: float = 0.10     # centre distance off the spacing by more: not a pair
    min_fill: float = 0.35          # visible share of a disc below which it is not used (wash-over)
    max_fill: float = 1.5           # a blob larger than this share of the disc is something else
    min_roundness: float = 0.6      # minor / major axis on the pond of a whole disc
    ring_hole: float = 0.15         # a centred hole of this share of the outline: a lifebuoy
    anchored_fill: float = 0.85     # share of the disc orange where a blue disc's partner must be
    anchored_rim: float = 0.6       # and at most this share of a circle 0.15 of its diameter outside it
    coarse_px: float = 7.0          # the blue disc's diameter in pixels the whole-frame pass keeps
    max_coarse: int = 4             # most the whole frame is downscaled

    def __post_init__(self):
        for name in ("orange_hsv", "blue_hsv"):
            lo, hi = getattr(self, name)
            if len(lo) != 3 or len(hi) != 3 or any(a > b for a, b in zip(lo, hi, strict=True)):
                raise ValueError(f"{name}: expected (lo, hi) HSV triples with lo <= hi, got {lo}, {hi}")
        for name in ("orange_diameter_m", "blue_diameter_m", "spacing_m", "spacing_tol_m", "coarse_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0")


@dataclass(frozen=True)
class FloatFix:
    x_m: float
    y_m: float
    heading_rad: float
    confidence: float       # 0..1
    heading_known: bool = True   # False: the orange disc alone (its blue not made out); heading a guess


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


@lru_cache(maxsize=8)
def _coarse_factor(h_bytes: bytes, width: int, height: int, blue_d: float, want_px: float, most: int) -> int:
    """Downscale for the whole-frame pass: the blue disc keeps ``want_px`` across almost everywhere."""
    H = np.frombuffer(h_bytes).reshape(3, 3)
    u, v = np.meshgrid(np.linspace(0, width - 1, 9), np.linspace(0, height - 1, 7))
    px = np.c_[u.ravel(), v.ravel()]
    across = blue_d / np.sqrt(_m2_per_px(H, px))
    across = across[np.isfinite(across)]
    if not len(across):
        return 1
    return int(np.clip(np.percentile(across, 10) // want_px, 1, most))


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


def _wrap(a: float) -> float:
    return math.pi - (math.pi - a) % (2 * math.pi)


def _mask(hsv: np.ndarray, band, share: float) -> np.ndarray:
    """Pixels in the HSV band. Where most of the window is in it, the water itself has that hue
    (blue water, brown muddy water): then only pixels more saturated than nearly all of it count."""
    lo, hi = band
    m = cv2.inRange(hsv, lo, hi)
    if cv2.countNonZero(m) > share * m.size:
        s = hsv[..., 1][m > 0]
        floor = int(min(254, np.percentile(s, 95) + 12))
        m = cv2.inRange(hsv, (lo[0], max(lo[1], floor), lo[2]), hi)
    return m


def _search(frame: np.ndarray, H: np.ndarray, params: FloatParams, box: tuple[int, int, int, int],
            scale: int, guided: bool = False) -> FloatFix | None:
    """The float in pixel window ``box`` (searched ``scale`` times downscaled): the discs as blobs and
    paired; else the blue disc looked for round an orange one (float_blue.py), or the orange one round
    a blue one; with ``guided`` (the tracker's window) an orange disc alone gives the position."""
    u0, v0, u1, v1 = box
    crop = frame[v0:v1, u0:u1]
    if scale > 1:
        crop = cv2.resize(crop, ((u1 - u0) // scale, (v1 - v0) // scale), interpolation=cv2.INTER_AREA)
    if crop.size == 0:
        return None
    hsv = cv2.cvtColor(crop, cv2.COLOR_BGR2HSV)
    origin = np.array([u0, v0], dtype=float)
    whole = (u1 - u0) * (v1 - v0) >= 0.5 * frame.shape[0] * frame.shape[1]
    share = WATER_SHARE_FRAME if whole else WATER_SHARE_WINDOW
    blues = _discs(H, _mask(hsv, params.blue_hsv, share), origin, scale, params.blue_diameter_m, params)
    oranges = _discs(H, _mask(hsv, params.orange_hsv, share), origin, scale, params.orange_diameter_m, params)
    best, best_score = None, 0.0
    for o in oranges:
        for b in blues:
            d = b.centre - o.centre
            off = abs(math.hypot(*d) - params.spacing_m) / params.spacing_tol_m
            if off >= 1:
                continue
            score = o.conf * b.conf * (1 - 0.5 * off * off)
            if score > best_score:
                best, best_score = (o.centre, d), score
    known = True
    if best is None:
        best, best_score = _round_orange(frame, H, params, oranges)
    if best is None and blues:
        best, best_score = _anchored(hsv, H, params, blues, origin, scale)
    if best is None and guided and oranges:
        o = max(oranges, key=lambda d: d.conf)
        if o.conf >= 0.5:
            best, best_score, known = (o.centre, np.array([params.spacing_m, 0.0])), 0.5 * o.conf, False
    if best is None:
        return None
    c, d = best
    return FloatFix(float(c[0]), float(c[1]), _wrap(math.atan2(d[1], d[0])), float(np.clip(best_score, 0, 1)),
                    known)


def _round_orange(frame, H, params: FloatParams, oranges: list[_Disc]):
    """The blue disc on the circle of the spacing round an orange one (float_blue.py):
    ((centre, orange -> blue), score) or (None, 0)."""
    best, best_score = None, 0.0
    for o in sorted(oranges, key=lambda d: -d.conf)[:4]:
        found = blue_bearing(frame, H, o.centre, blue_diameter_m=params.blue_diameter_m, spacing_m=params.spacing_m,
                             orange_diameter_m=params.orange_diameter_m)
        if found is None:
            continue
        bearing, conf = found
        score = 0.8 * o.conf * conf
        if score > best_score:
            best = (o.centre, params.spacing_m * np.array([math.cos(bearing), math.sin(bearing)]))
            best_score = score
    return best, best_score


def _disc_grid(diameter: float, n: int = 9) -> np.ndarray:
    g = (np.arange(n) + 0.5) / n * diameter - diameter / 2
    pts = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    return pts[np.hypot(pts[:, 0], pts[:, 1]) <= diameter / 2]


def _anchored(hsv: np.ndarray, H: np.ndarray, params: FloatParams, blues: list[_Disc], origin: np.ndarray,
              scale: int):
    """The orange disc where a blue disc's partner must be (module docstring): ((centre, orange ->
    blue), score) or (None, 0)."""
    mask = _mask(hsv, params.orange_hsv, WATER_SHARE_WINDOW) > 0
    if not mask.any():
        return None, 0.0
    Hi = np.linalg.inv(H)
    h, w = mask.shape

    def orange(pts: np.ndarray) -> np.ndarray:          # (..., 2) pond points -> in the orange mask
        q = np.c_[pts.reshape(-1, 2), np.ones(pts[..., 0].size)] @ Hi.T
        uv = (q[:, :2] / q[:, 2:3] - origin - (scale - 1) / 2.0) / scale
        u, v = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h) & (q[:, 2] > 0)
        out = np.zeros(len(u), bool)
        out[inside] = mask[v[inside], u[inside]]
        return out.reshape(pts.shape[:-1])

    grid = _disc_grid(params.orange_diameter_m, 11)
    n = 144
    a = np.arange(n) * (2 * np.pi / n)
    best, best_score = None, 0.0
    for b in blues:
        fill = orange(b.centre - params.spacing_m * np.c_[np.cos(a), np.sin(a)][:, None, :] + grid[None]).mean(axis=1)
        k = int(np.argmax(fill))
        f = float(fill[k])
        if f < params.anchored_fill:
            continue
        # the middle of the run of bearings as orange as the best (beside a lifebuoy's ring the disc
        # stays nearly whole a little way round towards it: the run's middle, not its first)
        lo = hi = 0
        while lo < n // 2 and fill[(k - lo - 1) % n] >= f - 0.03:
            lo += 1
        while hi < n // 2 and fill[(k + hi + 1) % n] >= f - 0.03:
            hi += 1
        bearing = a[k] + (hi - lo) / 2 * (2 * np.pi / n)
        d = params.spacing_m * np.array([math.cos(bearing), math.sin(bearing)])
        t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
        rim = orange(b.centre - d + 0.65 * params.orange_diameter_m * np.c_[np.cos(t), np.sin(t)]).mean()  # 0.15 d out
        if rim > params.anchored_rim:                  # orange all round: a part of something bigger
            continue
        score = 0.5 * b.conf * f
        if score > best_score:
            best, best_score = (b.centre - d, d), score
    return best, best_score


def _box(H: np.ndarray, shape, x: float, y: float, r: float) -> tuple[int, int, int, int] | None:
    """Pixel window holding the pond circle (x, y, r); None when it reaches past the horizon."""
    a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    ring = np.c_[x + r * np.cos(a), y + r * np.sin(a), np.ones(16)] @ np.linalg.inv(H).T
    if not (np.all(ring[:, 2] > 0) or np.all(ring[:, 2] < 0)):
        return None
    px = ring[:, :2] / ring[:, 2:3]
    h, w = shape[:2]
    u0, v0 = np.floor(px.min(axis=0)).astype(int)
    u1, v1 = np.ceil(px.max(axis=0)).astype(int) + 1
    u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w), min(v1, h)
    return (u0, v0, u1, v1) if u1 - u0 >= 4 and v1 - v0 >= 4 else None


def _window(frame, H, params, x, y, r, guided: bool = False) -> FloatFix | None:
    box = _box(H, frame.shape, x, y, r)
    if box is None:
        return None
    area = (box[2] - box[0]) * (box[3] - box[1])
    scale = 1 if area <= 0.15 * frame.shape[0] * frame.shape[1] else _scale(frame, H, params)
    fix = _search(frame, H, params, box, scale, guided)
    return _refined(frame, H, params, fix) if scale > 1 else fix


def _refined(frame, H, params, fix: FloatFix | None) -> FloatFix | None:
    """A fix from a downscaled pass measured again at full resolution (kept if that finds less)."""
    if fix is None:
        return None
    again = _window(frame, H, params, fix.x_m, fix.y_m, params.spacing_m + params.orange_diameter_m)
    return again if again is not None and (again.heading_known or not fix.heading_known) else fix


def _scale(frame, H, params) -> int:
    h, w = frame.shape[:2]
    return _coarse_factor(np.ascontiguousarray(H, dtype=float).tobytes(), w, h, params.blue_diameter_m,
                          params.coarse_px, params.max_coarse)


def detect_float(frame_bgr: np.ndarray, H: np.ndarray, params: FloatParams = FloatParams(), *,
                 near: tuple[float, float, float] | None = None) -> FloatFix | None:
    """The float in a BGR frame, or None (a dropout). ``near=(x_m, y_m, radius_m)``: look there first;
    there (only) an orange disc whose blue is not made out gives a fix with ``heading_known`` False."""
    if frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3:
        raise ValueError(f"expected a colour (h, w, 3) frame, got shape {frame_bgr.shape}")
    H = np.asarray(H, dtype=float)
    if near is not None:
        fix = _window(frame_bgr, H, params, *near, guided=True)
        if fix is not None:
            return fix
    h, w = frame_bgr.shape[:2]
    scale = _scale(frame_bgr, H, params)
    fix = _search(frame_bgr, H, params, (0, 0, w, h), scale)
    return _refined(frame_bgr, H, params, fix) if scale > 1 else fix
