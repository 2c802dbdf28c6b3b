"""The fork's innermost point from the fish's outline, re-measured near a proposal at a pyramid level
whose pixel is ~1/48 of the fin's span.

A faint, half-transparent fin in dim water shows too little contrast for ``vision.fork``'s
mid-level crossings (the fish's level there is the peduncle's, the fin is a fraction of it). Its
outline against the local background (``vision.silhouettes.background_distance``: CIE Lab distance
in units of the background's own spread, the background measured with the fish masked out) is
still there: the crop around the proposal is thresholded against that background, the silhouette
met just ahead of the proposal kept, and the caudal notch is its deepest convexity defect near the
proposal whose hull edge (lobe tip to lobe tip) spans the body's axis. The innermost point is the
mean of the outline points within 0.7 px of the defect's depth (sub-pixel); the fin's axis is
perpendicular to the lobe tips' chord, its span their distance.
"""
from __future__ import annotations

import cv2
import numpy as np

from vision.fins import Fins

TARGET_PX = 48.0        # the fin's span in pixels of the level it is measured on


def _crop_z(level: np.ndarray, f: float, box: tuple[int, int, int, int], bg: np.ndarray, spread: np.ndarray,
            sx: float, sy: float) -> np.ndarray:
    """Distance of a level crop (x0, y0, w, h) to the working image's background, in spreads."""
    x0, y0, w, h = box
    crop = np.ascontiguousarray(level[y0:y0 + h, x0:x0 + w])
    if crop.ndim == 3:
        lab = cv2.cvtColor(crop[..., :3], cv2.COLOR_BGR2LAB).astype(np.float32)
    else:
        lab = crop.astype(np.float32)[..., None]
    # crop pixel -> full resolution -> working image
    xs = ((np.arange(w) + x0 + 0.5) / f + 0.5) / sx - 1.0
    ys = ((np.arange(h) + y0 + 0.5) / f + 0.5) / sy - 1.0
    mx, my = np.meshgrid(xs.astype(np.float32), ys.astype(np.float32))
    b = cv2.remap(bg, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(h, w, -1)
    s = cv2.remap(spread, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.linalg.norm(lab - b, axis=2) / np.maximum(s, 1e-3)


def outline_locate(pyr: list[np.ndarray], bg: np.ndarray, spread: np.ndarray, sx: float, sy: float,
                   fins: Fins, k: float = 2.0, min_depth: float = 0.12) -> tuple[Fins, np.ndarray]:
    """Forks re-measured on the outline near each proposal (full-resolution px; ``bg``, ``spread``:
    the working image's background model, ``sx``, ``sy``: full / working px). Returns the forks and
    which were found (others unchanged)."""
    N = len(fins)
    xy, angle, span = fins.xy.copy(), fins.angle.copy(), fins.span_px.copy()
    ok = np.zeros(N, bool)
    for n in range(N):                                   # a few dozen proposals
        lv = int(np.clip(np.floor(np.log2(max(span[n] / TARGET_PX, 1.0))), 0, len(pyr) - 1))
        f = 2.0 ** -lv
        level = pyr[lv]
        H, W = level.shape[:2]
        c = (xy[n] + 0.5) * f - 0.5
        r = int(np.ceil(0.9 * span[n] * f)) + 2
        x0, y0 = max(int(c[0]) - r, 0), max(int(c[1]) - r, 0)
        x1, y1 = min(int(c[0]) + r + 1, W), min(int(c[1]) + r + 1, H)
        if x1 - x0 < 8 or y1 - y0 < 8:
            continue
        z = _crop_z(level, f, (x0, y0, x1 - x0, y1 - y0), bg, spread, sx, sy)
        mask = (z > k).astype(np.uint8)
        nl, lab = cv2.connectedComponents(mask, connectivity=8)
        axis = np.array([np.cos(angle[n]), np.sin(angle[n])])
        probe = c - [x0, y0] + np.outer([0.2, 0.3, 0.45, 0.6], span[n] * f * axis)
        pi = np.rint(probe).astype(int)
        inb = (pi[:, 0] >= 0) & (pi[:, 0] < x1 - x0) & (pi[:, 1] >= 0) & (pi[:, 1] < y1 - y0)
        labs = lab[pi[inb, 1], pi[inb, 0]]
        labs = labs[labs > 0]
        if len(labs) == 0:
            continue
        comp = (lab == labs[0]).astype(np.uint8)
        contours, _ = cv2.findContours(comp, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        if not contours:
            continue
        cont = max(contours, key=len)
        if len(cont) < 8:
            continue
        try:
            defects = cv2.convexityDefects(cont, cv2.convexHull(cont, returnPoints=False))
        except cv2.error:
            continue
        if defects is None:
            continue
        pts = cont[:, 0].astype(np.float64)
        d = defects.reshape(-1, 4)
        normal = np.array([-axis[1], axis[0]])
        centre = c - [x0, y0]
        best, best_depth = None, min_depth * span[n] * f
        for s_i, e_i, f_i, depth in d:
            dep = depth / 256.0
            p = pts[f_i]
            if dep < best_depth or np.linalg.norm(p - centre) > 0.35 * span[n] * f:
                continue
            if ((pts[s_i] - p) @ normal) * ((pts[e_i] - p) @ normal) >= 0:
                continue
            best, best_depth = (s_i, e_i, f_i), dep
        if best is None:
            continue
        s_i, e_i, f_i = best
        a, b = pts[s_i], pts[e_i]
        chord = b - a
        nrm = np.array([-chord[1], chord[0]]) / max(np.linalg.norm(chord), 1e-9)
        if nrm @ axis < 0:
            nrm = -nrm
        # the outline between the lobe tips, its points deepest from the chord
        idx = np.arange(min(s_i, e_i), max(s_i, e_i) + 1)
        if not (min(s_i, e_i) <= f_i <= max(s_i, e_i)):
            idx = np.r_[np.arange(max(s_i, e_i), len(pts)), np.arange(0, min(s_i, e_i) + 1)]
        depth_all = (pts[idx] - a) @ nrm
        deep = pts[idx][depth_all >= depth_all.max() - 0.7]
        p = deep.mean(axis=0) + [x0, y0]
        xy[n] = (p + 0.5) / f - 0.5
        angle[n] = np.arctan2(nrm[1], nrm[0])
        span[n] = np.clip(np.linalg.norm(chord) / f, 0.5 * span[n], 2.0 * span[n])
        ok[n] = True
    return Fins(xy, angle, span, fins.score.copy(), fins.polarity.copy(),
                None if fins.body is None else fins.body.copy()), ok
