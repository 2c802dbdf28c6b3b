"""Where fins can be: the ends of fish-like bodies on the working image.

Measured on rendered pairs (bench/bench_survey_underwater.py, notes in the README), a bank of small
fork templates run over a whole frame (eq. 13 alone) ranks the true fork of a fully visible fish
among its best 80 peaks for fewer than a third of the fish: a faint, half-transparent fin against
blue-green water is a weak pattern beside the body's own strong edges, reef texture and other fish.
The bodies are the strong signal. So the bank is evaluated only where a fin can be: at the two ends
of each elongated region that is unlike the water (``illumination.water_distance`` above a
threshold set from the frame's own statistics). Each end is a fork hypothesis with the body's axis
as its angle and 0.3 of the region's length as its fin span; ``vision.fork`` keeps the ends that
show a fork (a V notch), which also tells the tail from the snout.
"""
from __future__ import annotations

import cv2
import numpy as np

from vision.fins import SPAN_OF_FL, Fins


def fish_masks(dist: np.ndarray, ks: tuple[float, ...] = (3.0,), otsu_share: float = 1.0) -> list[np.ndarray]:
    """uint8 masks (one per k) of pixels unlike the water: the distance above median + k * 1.4826 MAD
    of the frame and above ``otsu_share`` of Otsu's threshold (water and fish are the frame's two
    modes; a frame of water alone has one, and Otsu would split its noise); the higher k splits
    fish that touch at the lower one. Measured on 60 rendered scenes (110 fully visible fish, 77 of
    them before a reef or net, where the water distance is high in patches everywhere): half of
    Otsu's threshold leaves fewer fish without a region end near their fork (32 instead of 41) but
    its many more regions end in fewer measured fish (10 instead of 15)."""
    flat = dist[:: 2, :: 2].ravel()
    med = float(np.median(flat))
    mad = float(np.median(np.abs(flat - med))) * 1.4826
    top = max(float(np.quantile(flat, 0.999)), 1e-3)
    q = np.clip(dist * (255.0 / top), 0, 255).astype(np.uint8)
    otsu, _ = cv2.threshold(q, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    out = []
    for k in ks:
        mask = (dist > max(otsu_share * otsu * top / 255.0, med + k * max(mad, 1e-3))).astype(np.uint8)
        out.append(cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)))
    return out


def body_ends(mask: np.ndarray, sx: float, sy: float, min_len_px: float, min_elong: float = 1.8,
              max_bodies: int = 30) -> tuple[Fins, np.ndarray]:
    """Fork hypotheses at both ends of every elongated region of ``mask`` at least ``min_len_px``
    long (working-image px), in full-resolution px (``sx``, ``sy``: full / working). Returns the
    hypotheses (2 per body: end, angle towards the other end, span 0.3 of the length) and, per
    hypothesis, the body length in full-resolution px."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    big = np.flatnonzero((np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) >= min_len_px)
                         & (np.arange(n) > 0))
    big = big[np.argsort(-stats[big, cv2.CC_STAT_AREA])][:max_bodies]
    xy, ang, length = [], [], []
    for lab in big:                                      # a few dozen bodies
        x0, y0, w, h = stats[lab, :4]
        ys, xs = np.nonzero(labels[y0:y0 + h, x0:x0 + w] == lab)
        pts = np.c_[xs + x0, ys + y0].astype(np.float64)
        c = pts.mean(axis=0)
        cov = np.cov((pts - c).T)
        evals, evecs = np.linalg.eigh(cov)
        if evals[0] <= 0 or np.sqrt(evals[1] / evals[0]) < min_elong:
            continue
        axis = evecs[:, 1]
        t = (pts - c) @ axis
        lo, hi = np.quantile(t, [0.002, 0.998])
        if hi - lo < min_len_px:
            continue
        for end, toward in ((lo, 1.0), (hi, -1.0)):
            # the end's point on the axis, in full-resolution px (pixel centres)
            p = c + end * axis
            xy.append(((p[0] + 0.5) * sx - 0.5, (p[1] + 0.5) * sy - 0.5))
            d = toward * axis * np.array([sx, sy])
            ang.append(np.arctan2(d[1], d[0]))
            length.append((hi - lo) * 0.5 * (sx + sy))
    if not xy:
        return Fins.empty(), np.zeros(0)
    length = np.array(length)
    ang = np.array(ang)
    fins = Fins(np.array(xy), ang, SPAN_OF_FL * length, np.ones(len(xy)), np.ones(len(xy)), ang.copy())
    return fins, length
