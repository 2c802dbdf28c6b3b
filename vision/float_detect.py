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
from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np

from vision.float_blue import blue_bearing
from vision.float_discs import _Disc, _discs, _m2_per_px

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
    others: tuple[tuple[float, float], ...] = ()   # other whole markers in the same search (pond x, y)


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
            scale: int, guided: bool = False, centre: np.ndarray | None = None) -> FloatFix | None:
    """The float in pixel window ``box`` (searched ``scale`` times downscaled): the discs as blobs and
    paired; else the blue disc looked for round an orange one (float_blue.py), or the orange one round
    a blue one; with ``guided`` (the tracker's window) an orange disc alone gives the position.
    Of two whole markers, the one nearest ``centre`` (the track's prediction) is the fix and the
    other is among its ``others``: a spare float beside ours, both in the window, was taken by its
    score."""
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
    pairs = []
    for o in oranges:
        for b in blues:
            d = b.centre - o.centre
            off = abs(math.hypot(*d) - params.spacing_m) / params.spacing_tol_m
            if off < 1:
                pairs.append((o.conf * b.conf * (1 - 0.5 * off * off), o.centre, d))
    if not guided and _two_floats(pairs, params):
        return None                  # which is ours? Not a guess: a dropout until one is tracked
    best, best_score, others = _chosen(pairs, params, centre)
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
                    known, others)


def _chosen(pairs: list, params: FloatParams, centre: np.ndarray | None):
    """((centre, orange -> blue), score, others) of the marker taken from ``pairs`` (score, centre,
    offset): the surest, or with ``centre`` the nearest it among those nearly as sure (then the
    surest pairing of that marker's discs); ``others``: the rest of those, markers apart from it."""
    if not pairs:
        return None, 0.0, ()
    top = max(p[0] for p in pairs)
    sure = [p for p in pairs if p[0] >= 0.5 * top]
    pick = max(sure, key=lambda p: p[0])
    if centre is not None:
        near = min(sure, key=lambda p: float(np.linalg.norm(p[1] - centre)))
        pick = max((p for p in sure if np.linalg.norm(p[1] - near[1]) <= 2 * params.spacing_m), key=lambda p: p[0])
    others = tuple((float(p[1][0]), float(p[1][1])) for p in sure
                   if np.linalg.norm(p[1] - pick[1]) > 2 * params.spacing_m)
    return (pick[1], pick[2]), pick[0], others


def _two_floats(pairs: list, params: FloatParams) -> bool:
    """Two whole markers in view, apart and nearly as sure: the search of the whole frame cannot
    tell the cleaner's (a probe's static second float was tracked with full confidence, 10 m off)."""
    return bool(_chosen(pairs, params, None)[2])


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
    fix = _search(frame, H, params, box, scale, guided, np.array([x, y]) if guided else None)
    return _refined(frame, H, params, fix) if scale > 1 else fix


def _refined(frame, H, params, fix: FloatFix | None) -> FloatFix | None:
    """A fix from a downscaled pass measured again at full resolution (kept if that finds less)."""
    if fix is None:
        return None
    again = _window(frame, H, params, fix.x_m, fix.y_m, params.spacing_m + params.orange_diameter_m)
    if again is None or not (again.heading_known or not fix.heading_known):
        return fix
    return replace(again, others=fix.others)


def _scanned(frame, H, params, fix: FloatFix) -> FloatFix:
    """``fix`` with every other whole marker of the frame among its ``others`` (the tracker keeps
    them as spares: a spare 1 m off took the track while ours was hidden for 2.5 s)."""
    h, w = frame.shape[:2]
    seen = _search(frame, H, params, (0, 0, w, h), _scale(frame, H, params), True, np.array([fix.x_m, fix.y_m]))
    if seen is None:
        return fix
    found = list(seen.others) + ([(seen.x_m, seen.y_m)] if seen.heading_known else [])
    apart = [xy for xy in found if math.hypot(xy[0] - fix.x_m, xy[1] - fix.y_m) > 2 * params.spacing_m]
    return replace(fix, others=fix.others + tuple(apart))


def _scale(frame, H, params) -> int:
    h, w = frame.shape[:2]
    return _coarse_factor(np.ascontiguousarray(H, dtype=float).tobytes(), w, h, params.blue_diameter_m,
                          params.coarse_px, params.max_coarse)


def detect_float(frame_bgr: np.ndarray, H: np.ndarray, params: FloatParams = FloatParams(), *,
                 near: tuple[float, float, float] | None = None, scan: bool = False) -> FloatFix | None:
    """The float in a BGR frame, or None (a dropout). ``near=(x_m, y_m, radius_m)``: look there first;
    there (only) an orange disc whose blue is not made out gives a fix with ``heading_known`` False.
    ``scan``: a fix found there also lists the frame's other whole markers (a whole-frame pass)."""
    if frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3:
        raise ValueError(f"expected a colour (h, w, 3) frame, got shape {frame_bgr.shape}")
    H = np.asarray(H, dtype=float)
    if near is not None:
        fix = _window(frame_bgr, H, params, *near, guided=True)
        if fix is not None:
            return _scanned(frame_bgr, H, params, fix) if scan else fix
    h, w = frame_bgr.shape[:2]
    scale = _scale(frame_bgr, H, params)
    fix = _search(frame_bgr, H, params, (0, 0, w, h), scale)
    return _refined(frame_bgr, H, params, fix) if scale > 1 else fix
