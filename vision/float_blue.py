"""The blue disc found from the orange one, where it is too small or too little blue for a blob.

A 0.20 m disc 15 m from an 8 m tower is 2-3 pixels across on a 640-pixel-wide camera, and a
JPEG stream with halved chroma (4:2:0, what IP cameras send) smears its blue over the water round
it: no blob of blue pixels is left to find, but the blue is still there, spread. And a blue disc
floating over a blue tarp makes one blob with it, too large for a disc. Both are found by where the
blue disc must be: on the circle of the spacing (0.40 m) round the orange disc's centre.

For each of 72 bearings round the orange centre the disc's footprint is sampled (sub-pixel,
bilinear, through H: the same pond points whatever the frame's size) with a ring round it, cut in
eight sectors; ring samples on the orange disc are left out. Colours are opponent colours (chroma
fully, brightness half: a shadow or glare veil is not a colour). A bearing's score is how far its
disc's colour lies off every *mix* of two sectors' colours, and off the colour of any one ring
sample: a disc of its own paint on water, or on a tarp of another hue or saturation, is none of
them; a footprint straddling the edge of a tarp is a mix of the tarp and the water beside it, and
a footprint inside a blue thing larger than the disc matches the ring where that thing reaches it
— both score nothing. So a blue disc on a tarp of its own blue gives no bearing (the detector then
reports the position alone), never a wrong one. The ring lies 1.5 pixels outside the disc (a pixel
in pond metres at that place, through H: a minimum size derived from H, not a constant), so the
disc's own blur is not its background. A bearing counts only if its disc is bluer than the water
(the window's median). Where the disc is big enough in the frame to be seen whole (``FILL_CHECK_PX``),
its blue must fill at least ``MIN_FILL`` of the footprint: a small blue tag on an orange buoy of the
float's size is not the marker.

The peak bearing is refined by a parabola through its neighbours. It is taken when it stands
clear of the water's noise (the window's own spread, robustly, over the root of the pixels the
disc covers) and of every bearing more than a right angle away (a blue ball beside the float
gives a second peak: ambiguous, refused).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

BEARINGS = 72
SECTORS = 8          # the ring round a bearing's disc, cut in sectors
# opponent colour axes (rows, on B, G, R): red-green, yellow-blue, brightness (weighed half below)
_OPP = np.array([[0.0, -1.0, 1.0], [-2.0, 1.0, 1.0], [1.0, 1.0, 1.0]]) \
    / np.array([[2 ** 0.5], [6 ** 0.5], [2 * 3 ** 0.5]])
_BLUE_AXIS = np.array([1.0, -0.5, -0.5])   # B - (G + R) / 2: how much bluer than its grey
FILL_CHECK_PX = 30.0  # a disc covering this many pixels (~6 across) or more is seen whole: its fill is judged
MIN_FILL = 0.5        # ... the least share of its footprint samples at half its blue or more (a full disc
                      # ~1, blurred; 0.14 m 0.68; a 0.10 m one, a quarter of the area, 0.38)


def _grid(radius: float, n: int) -> np.ndarray:
    g = (np.arange(n) + 0.5) / n * 2 * radius - radius
    pts = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    return pts[np.hypot(pts[:, 0], pts[:, 1]) <= radius]


def _to_px(Hi: np.ndarray, xy: np.ndarray) -> np.ndarray:
    h = xy @ Hi[:, :2].T + Hi[:, 2]
    return h[:, :2] / h[:, 2:3]


def _pixel_m(H: np.ndarray, Hi: np.ndarray, xy: np.ndarray) -> float:
    """The larger pond extent (m) of one pixel at pond point ``xy``."""
    p = _to_px(Hi, xy[None])[0]
    q = np.c_[np.array([p, p + (1, 0), p + (0, 1)]), np.ones(3)] @ H.T
    q = q[:, :2] / q[:, 2:3]
    return float(max(np.hypot(*(q[1] - q[0])), np.hypot(*(q[2] - q[0]))))


def blue_bearing(frame_bgr: np.ndarray, H: np.ndarray, orange_xy, *, blue_diameter_m: float, spacing_m: float,
                 orange_diameter_m: float,
                 min_contrast: float = 6.0, noise_k: float = 4.0, clear: float = 0.6):
    """(bearing_rad, confidence) of the blue disc round the orange centre ``orange_xy`` (pond m), or
    None when no bearing stands clear (module docstring). ``min_contrast``: grey levels of colour
    difference a disc needs at least; ``noise_k``: and this many times the water's spread; ``clear``:
    every bearing more than 90 degrees off the peak scores under this share of it."""
    H = np.asarray(H, float)
    Hi = np.linalg.inv(H)
    o = np.asarray(orange_xy, float)
    r = blue_diameter_m / 2
    px_m = _pixel_m(H, Hi, o)
    ring_in, ring_out = r + 1.5 * px_m, r + 1.5 * px_m + max(0.05, 1.5 * px_m)
    a = np.arange(BEARINGS) * (2 * np.pi / BEARINGS)
    centres = o + spacing_m * np.c_[np.cos(a), np.sin(a)]                   # (B, 2)
    disc = _grid(r, 7)                                                       # (D, 2)
    t = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    ring = np.r_[np.c_[np.cos(t), np.sin(t)] * ring_in, np.c_[np.cos(t), np.sin(t)] * ring_out]   # (64, 2)
    sector = np.tile(np.arange(32) * SECTORS // 32, 2)
    pts = np.concatenate([(centres[:, None] + disc[None]).reshape(-1, 2),
                          (centres[:, None] + ring[None]).reshape(-1, 2)])
    uv = _to_px(Hi, pts)
    if not np.all(np.isfinite(uv)):
        return None
    h, w = frame_bgr.shape[:2]
    u0, v0 = np.maximum(np.floor(uv.min(axis=0)).astype(int) - 2, 0)
    u1, v1 = np.minimum(np.ceil(uv.max(axis=0)).astype(int) + 3, (w, h))
    if u1 - u0 < 3 or v1 - v0 < 3:
        return None
    crop = frame_bgr[v0:v1, u0:u1].astype(np.float32)
    water = np.median(crop.reshape(-1, 3), axis=0)
    spread = 1.4826 * np.median(np.abs(crop.reshape(-1, 3) @ _OPP.T - water @ _OPP.T), axis=0)
    loc = (uv - (u0, v0)).astype(np.float32)
    inside = (loc[:, 0] >= 0) & (loc[:, 0] <= u1 - u0 - 1) & (loc[:, 1] >= 0) & (loc[:, 1] <= v1 - v0 - 1)
    bgr = cv2.remap(crop, loc[:, 0:1].copy(), loc[:, 1:2].copy(), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)
    col = bgr @ (_OPP * np.array([[1.0], [1.0], [0.5]])).T
    nd, nb = len(disc), BEARINGS * len(disc)
    seen = inside[:nb].reshape(BEARINGS, nd).mean(axis=1) > 0.5
    dmean = col[:nb].reshape(BEARINGS, nd, 3).mean(axis=1)                   # (B, 3)
    rcol = col[nb:].reshape(BEARINGS, len(ring), 3)
    # the ring's samples on the orange disc (and its blur) are not the disc's background
    rpts = pts[nb:].reshape(BEARINGS, len(ring), 2)
    bare = np.hypot(*(rpts - o).transpose(2, 0, 1)) > orange_diameter_m / 2 + 1.5 * px_m
    sums = np.stack([(rcol * (bare & (sector == k))[..., None]).sum(axis=1) for k in range(SECTORS)], axis=1)
    counts = np.stack([(bare & (sector == k)).sum(axis=1) for k in range(SECTORS)], axis=1)   # (B, S)
    used = counts >= 3
    smean = sums / np.maximum(counts, 1)[..., None]                           # (B, S, 3)
    # the disc's colour off every mix of two sectors' colours: a footprint straddling the edge of a
    # tarp (or of anything) is such a mix, a disc of its own paint is not
    i, j = np.triu_indices(SECTORS)
    si, e = smean[:, i], smean[:, j] - smean[:, i]                             # (B, P, 3)
    rel = dmean[:, None] - si
    t = np.clip((rel * e).sum(axis=2) / np.maximum((e * e).sum(axis=2), 1e-9), 0.0, 1.0)
    off_mix = np.linalg.norm(rel - t[..., None] * e, axis=2)
    score = np.where(used[:, i] & used[:, j], off_mix, np.inf).min(axis=1)
    # nor the colour of any one spot of its ring: a blue thing bigger than the disc reaches one
    # (at a few pixels a disc the ring is large, and sector means mix a tarp with the water)
    score = np.minimum(score, np.where(bare, np.linalg.norm(rcol - dmean[:, None], axis=2), np.inf).min(axis=1))
    score = np.where(np.isfinite(score), score, 0.0)
    to_disc = np.where(used, np.linalg.norm(dmean[:, None] - smean, axis=2), np.inf).min(axis=1)
    bluer = (bgr[:nb].reshape(BEARINGS, nd, 3).mean(axis=1) - water) @ _BLUE_AXIS
    score = np.where(seen & (bluer > 0.3 * to_disc), score, 0.0)
    k = int(np.argmax(score))
    peak = float(score[k])
    q = np.c_[np.array([uv[0], uv[0] + (1, 0), uv[0] + (0, 1)]), np.ones(3)] @ H.T
    q = q[:, :2] / q[:, 2:3]
    disc_px = math.pi * r * r / max(abs(float(np.linalg.det(np.c_[q[1] - q[0], q[2] - q[0]]))), 1e-12)
    # the disc's mean is over the pixels it covers: the water's spread shrinks by their root
    floor = max(min_contrast, noise_k * float(np.hypot(spread[0], spread[1])) / math.sqrt(max(1.0, disc_px)))
    if peak < floor:
        return None
    if disc_px >= FILL_CHECK_PX:
        # big enough in the frame to be seen whole: the blue must fill the disc's footprint as a disc
        # does, not be a tag on it (a 0.06 m one on an orange buoy was taken at 0.8)
        excess = (bgr[k * nd:(k + 1) * nd] - water) @ _BLUE_AXIS
        top = float(np.quantile(excess, 0.9))
        if top <= 0 or float(np.mean(excess > 0.5 * top)) < MIN_FILL:
            return None
    off = np.abs(np.angle(np.exp(1j * (a - a[k]))))
    if float(score[off > np.pi / 2].max(initial=0.0)) > clear * peak:
        return None
    s0, s1, s2 = score[(k - 1) % BEARINGS], peak, score[(k + 1) % BEARINGS]
    den = s0 - 2 * s1 + s2
    frac = 0.5 * (s0 - s2) / den if den < 0 else 0.0
    bearing = a[k] + float(np.clip(frac, -0.5, 0.5)) * (2 * np.pi / BEARINGS)
    return math.remainder(bearing, 2 * math.pi), float(min(1.0, peak / (2 * floor)))
