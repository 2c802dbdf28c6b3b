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

Where proposals miss (measured 2026-12-02, bench/diag_underwater.py's "proposed" stage, seeds 0-39:
21 of 75 fully visible fish, 42 views, 5 of them with a proposal in that view but not the other;
every proposer of ``vision.underwater`` counted): in 19 views the nearest proposal is on the
fish's axis but 0.1-0.3 of its length ahead of the fork -- the half-transparent fin and a thin
peduncle are not in the region (the 3x3 opening at the 320 px working width cuts a peduncle under
~12 full-resolution px deep), so the region ends at the peduncle or short of it and the shifted
ends (``Params.end_offsets``, then back to 0.17 of the region) do not reach the notch; in 15 no
proposal is within 0.3 of the length (the fish merged with a fish it touches or overlaps into one
region whose ends are elsewhere, or cut up by a reef behind it); in 3 the proposals are beside the
axis (a region's axis tilted by an adjoining fish or the fish's shadow). Shifting the ends back
further (-0.3 of the region, outlines' -0.25) proposes 4-5 more fish in 40 scenes (54 -> 58,
57 -> 62 of 75 / 97; both runs with the arms refitted, vision.fork) but finds no more (19 -> 21, 23 -> 22: the
post-filters drop them).
"""
from __future__ import annotations

import cv2
import numpy as np

from vision import order_stats
from vision.fins import SPAN_OF_FL, Fins
from vision.labels import regions


def fish_masks(dist: np.ndarray, ks: tuple[float, ...] = (3.0,), otsu_share: float = 1.0) -> list[np.ndarray]:
    """uint8 masks (one per k) of pixels unlike the water: the distance above median + k * 1.4826 MAD
    of the frame and above ``otsu_share`` of Otsu's threshold (water and fish are the frame's two
    modes; a frame of water alone has one, and Otsu would split its noise); the higher k splits
    fish that touch at the lower one. Measured on 60 rendered scenes (110 fully visible fish, 77 of
    them before a reef or net, where the water distance is high in patches everywhere): half of
    Otsu's threshold leaves fewer fish without a region end near their fork (32 instead of 41) but
    its many more regions end in fewer measured fish (10 instead of 15)."""
    flat = dist[:: 2, :: 2].ravel()
    med = order_stats.median(flat)
    mad = order_stats.median(np.abs(flat - med)) * 1.4826
    top = max(order_stats.quantile(flat, 0.999), 1e-3)
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
    n, labels, stats, _ = regions(mask)
    big = np.flatnonzero((np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) >= min_len_px)
                         & (np.arange(n) > 0))
    big = big[np.argsort(-stats[big, cv2.CC_STAT_AREA])][:max_bodies]
    xy, ang, length = [], [], []
    if len(big):
        # every body's pixels at once (no loop over bodies or pixels): moments by bincount, the
        # axis from each 2x2 covariance, the ends at the 0.2 % / 99.8 % quantiles along it
        slot = np.full(n, -1, np.int64)
        slot[big] = np.arange(len(big))
        g = slot[labels]
        ys, xs = np.nonzero(g >= 0)
        gi = g[ys, xs]
        B = len(big)
        cnt = np.bincount(gi, minlength=B).astype(np.float64)
        cx = np.bincount(gi, xs.astype(np.float64), B) / cnt
        cy = np.bincount(gi, ys.astype(np.float64), B) / cnt
        dx, dy = xs - cx[gi], ys - cy[gi]
        dof = np.maximum(cnt - 1, 1)
        sxx, sxy, syy = (np.bincount(gi, a * b, B) / dof for a, b in ((dx, dx), (dx, dy), (dy, dy)))
        evals, evecs = np.linalg.eigh(np.stack([np.column_stack((sxx, sxy)), np.column_stack((sxy, syy))], axis=1))
        axis = evecs[:, :, 1]                                                   # (B, 2)
        t = dx * axis[gi, 0] + dy * axis[gi, 1]
        srt, start = _sorted_by_body(t, gi, cnt.astype(np.int64))
        lo, hi = (_quantile_sorted(srt, start, cnt.astype(np.int64), q) for q in (0.002, 0.998))
        for b in range(B):                                                      # a few dozen bodies
            if evals[b, 0] <= 0 or np.sqrt(evals[b, 1] / evals[b, 0]) < min_elong or hi[b] - lo[b] < min_len_px:
                continue
            c = np.array([cx[b], cy[b]])
            for end, toward in ((lo[b], 1.0), (hi[b], -1.0)):
                # the end's point on the axis, in full-resolution px (pixel centres)
                p = c + end * axis[b]
                xy.append(((p[0] + 0.5) * sx - 0.5, (p[1] + 0.5) * sy - 0.5))
                d = toward * axis[b] * np.array([sx, sy])
                ang.append(np.arctan2(d[1], d[0]))
                length.append((hi[b] - lo[b]) * 0.5 * (sx + sy))
    if not xy:
        return Fins.empty(), np.zeros(0)
    length = np.array(length)
    ang = np.array(ang)
    fins = Fins(np.array(xy), ang, SPAN_OF_FL * length, np.ones(len(xy)), np.ones(len(xy)), ang.copy())
    return fins, length


def _sorted_by_body(t: np.ndarray, body: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The values ``t`` grouped by ``body`` (0..B-1, ``count`` of each), ascending within each group,
    and where each group starts: np.lexsort((t, body))'s order, ~10x faster (a radix sort of the
    small body numbers, then numpy's vectorised sort of each body's values; a few dozen bodies)."""
    small = np.int16 if len(count) < 2**15 else np.int64
    grouped = t[np.argsort(body.astype(small), kind="stable")]
    start = np.concatenate(([0], np.cumsum(count)))
    for b in range(len(count)):
        grouped[start[b]:start[b + 1]].sort()
    return grouped, start[:-1]


def _quantile_sorted(values: np.ndarray, start: np.ndarray, count: np.ndarray, q: float) -> np.ndarray:
    """np.quantile(..., q) (linear) of each group of ``values``, sorted within groups that begin at
    ``start`` and hold ``count`` values."""
    pos = q * (count - 1)
    k = np.floor(pos).astype(np.int64)
    frac = pos - k
    a = values[start + k]
    b = values[start + np.minimum(k + 1, count - 1)]
    return np.where(frac >= 0.5, b - (b - a) * (1 - frac), a + (b - a) * frac)
