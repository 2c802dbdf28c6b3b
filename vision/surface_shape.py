"""A fish's front and rear points from its silhouette seen from above (the paper's Fig. 6).

The body axis is the principal axis of the region's pixels; the midline is the mean lateral position
of the pixels in slices across it (so a moderately bent fish keeps a midline on its body). Which end
is the head is decided by shape, two cues weighed together:

  * the caudal fork: a notch (convexity defect of the outline) at one end, between two lobes on
    either side of the midline, deeper than a few per cent of the length;
  * the taper: a fish is widest about a third of its length behind the snout and narrows to the
    caudal peduncle, so the band 15-45 % from the head end is wider than the same band from the tail.

The front point is the snout tip: the outline's extreme along the local head direction (the midline's
direction near the head). The rear point is the innermost point of the caudal fork: the notch's
deepest point when a fork is found, else the outline's extreme at the tail end (a fish with an
unforked tail: fork length = total length). Intermediate points lie on the midline between them.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vision.surface_regions import Region


@dataclass
class Fish2D:
    snout: np.ndarray          # (2,) px
    fork: np.ndarray           # (2,) px
    mid: np.ndarray            # (K, 2) px, intermediate midline points from snout to fork
    length_px: float
    width_px: float            # widest slice
    head_conf: float           # 0..1, how clearly the shape says which end is the head
    fork_depth: float          # notch depth / length (0: no fork found)
    elongation: float          # length / mean width
    glare: float
    peak: float


N_SLICES = 24
N_MID = 5


def _ends_defects(contour: np.ndarray, s: np.ndarray, t_rel: np.ndarray, L: float, lo: float, hi: float):
    """Deepest fork notch at each end: ((depth, index) at the low end, (depth, index) at the high end)."""
    pts = contour.astype(np.int32).reshape(-1, 1, 2)
    best = [(0.0, -1), (0.0, -1)]
    try:
        hull = cv2.convexHull(pts, returnPoints=False)
        if hull is None or len(hull) < 4:
            return best
        defects = cv2.convexityDefects(pts, np.sort(hull, axis=0))
    except cv2.error:
        return best
    if defects is None:
        return best
    d = defects.reshape(-1, 4)
    a, b, far, depth = d[:, 0], d[:, 1], d[:, 2], d[:, 3] / 256.0
    zone = 0.3 * L
    lobes = np.sign(t_rel[a]) * np.sign(t_rel[b]) < 0           # lobes on either side of the midline
    central = np.abs(t_rel[far]) < 0.25 * L
    for end, near in ((0, s[far] < lo + zone), (1, s[far] > hi - zone)):
        ok = lobes & central & near & (depth > 0.025 * L)
        if ok.any():
            j = int(np.flatnonzero(ok)[np.argmax(depth[ok])])
            best[end] = (float(depth[j] / L), int(far[j]))
    return best


def _extreme(contour: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Tip of the outline along a direction: the mean of the points within 0.75 px of the extreme
    (a blunt snout's tip is its middle), pushed out to the extreme."""
    proj = contour @ direction
    top = proj.max()
    near = contour[proj >= top - 0.75]
    tip = near.mean(axis=0)
    return tip + (top - tip @ direction) * direction


def analyse(r: Region) -> Fish2D | None:
    """Front/rear/intermediate points of one region; None if it is not fish-shaped."""
    ys, xs = np.nonzero(r.mask)
    if len(xs) < 20:
        return None
    pix = np.c_[xs, ys].astype(np.float64) + r.origin
    centre = pix.mean(axis=0)
    cov = np.cov((pix - centre).T)
    lam, vec = np.linalg.eigh(cov)
    e = vec[:, 1]
    n = np.array([-e[1], e[0]])
    s_pix, t_pix = (pix - centre) @ e, (pix - centre) @ n
    s_c, t_c = (r.contour - centre) @ e, (r.contour - centre) @ n
    lo, hi = float(s_c.min()), float(s_c.max())
    L = hi - lo
    if L < 8:
        return None
    # width and midline per slice across the axis
    k = np.clip(((s_pix - lo) / L * N_SLICES).astype(int), 0, N_SLICES - 1)
    count = np.bincount(k, minlength=N_SLICES).astype(float)
    width = count * N_SLICES / L
    tmid = np.bincount(k, weights=t_pix, minlength=N_SLICES) / np.maximum(count, 1)
    centres = lo + (np.arange(N_SLICES) + 0.5) * L / N_SLICES
    elong = L / max(float(count.sum()) / L, 1.0)
    # fork and taper cues, positive = the high end (s = hi) is the head
    kc = np.clip(((s_c - lo) / L * N_SLICES).astype(int), 0, N_SLICES - 1)
    t_rel = t_c - tmid[kc]
    (d_lo, i_lo), (d_hi, i_hi) = _ends_defects(r.contour, s_c, t_rel, L, lo, hi)
    band = slice(int(0.15 * N_SLICES), int(0.45 * N_SLICES) + 1)
    w_lo, w_hi = width[band].mean(), width[::-1][band].mean()
    taper = (w_hi - w_lo) / max(w_hi + w_lo, 1e-9)
    evidence = 6.0 * taper + 25.0 * (d_lo - d_hi)
    head_hi = evidence >= 0
    head_conf = float(np.tanh(abs(evidence)))
    # local directions at both ends from the midline
    def along(frac):
        j = min(int(frac * N_SLICES), N_SLICES - 1)
        return centre + centres[j] * e + tmid[j] * n
    dir_hi = along(0.92) - along(0.6)
    dir_lo = along(0.08) - along(0.4)
    dir_hi /= max(np.linalg.norm(dir_hi), 1e-9)
    dir_lo /= max(np.linalg.norm(dir_lo), 1e-9)
    if head_hi:
        snout = _extreme(r.contour, dir_hi)
        fork_i, fork_d, tail_dir = i_lo, d_lo, dir_lo
    else:
        snout = _extreme(r.contour, dir_lo)
        fork_i, fork_d, tail_dir = i_hi, d_hi, dir_hi
    fork = r.contour[fork_i].astype(float) if fork_i >= 0 else _extreme(r.contour, tail_dir)
    fr = np.linspace(0, 1, N_MID + 2)[1:-1]
    s_f = (snout - centre) @ e + fr * ((fork - centre) @ e - (snout - centre) @ e)
    t_f = np.interp(s_f, centres, tmid)
    mid = centre + s_f[:, None] * e + t_f[:, None] * n
    return Fish2D(snout, fork, mid, float(np.linalg.norm(snout - fork)), float(width.max()), head_conf,
                  fork_d, float(elong), r.glare, r.peak)
