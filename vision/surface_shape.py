"""A fish's front and rear points from its silhouette seen from above (the paper's Fig. 6).

The body axis is the principal axis of the region's pixels; the midline is the mean lateral position
of the pixels in slices across it (so a moderately bent fish keeps a midline on its body). Which end
is the head is decided by shape, three cues weighed together:

  * the caudal fork: a notch (convexity defect of the outline) at one end, between two lobes on
    either side of the midline, deeper than a few per cent of the length;
  * the taper: a fish is widest about a third of its length behind the snout and narrows to the
    caudal peduncle, so the band 15-45 % from the head end is wider than the same band from the tail;
  * the caudal fin: paler than the body, it runs on past the body's end at the tail only.

The front point is the snout tip: the outline's extreme along the local head direction (the midline's
direction near the head). The rear point is the innermost point of the caudal fork: the notch's
deepest point when a fork is found, else placed from the body's rear end (the caudal fin's base) by
the species' ratio, or the outline's extreme at the tail end (a fish with an unforked tail: fork
length = total length). The body's rear end is followed on along a caudal peduncle too thin for the
outline (``_peduncle_end``), unless what it followed runs on past the fork: a caudal fin as dark as
the peduncle (``_runs_past_fork``); nor, from wherever it was found, along a caudal fin seen edge-on
as a dark line of even width a step thinner than the body (``_fin_line_start``). Intermediate points
lie on the midline between them.
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
    base: np.ndarray | None = None    # (2,) px, the body's rear end (caudal fin base, fins excluded)
    tip: np.ndarray | None = None     # (2,) px, the rear end with the pale caudal fin
    notch: np.ndarray | None = None   # (2,) px, the fork notch when one is seen
    fork_seen: bool = False           # ``fork`` is the notch seen (not placed from the fin base)
    centre: np.ndarray | None = None  # (2,) px, centroid of the body's pixels
    snout_conf: float = 0.0           # the learned snout locator's confidence in ``snout`` (0: not used)
    base_conf: float = 0.0            # the learned body-end locator's in ``base`` (vision.surface_nets)


N_SLICES = 24
PEDUNCLE_LEVEL = 0.3   # the body's end followed along a thin peduncle to where its ridge falls below
                       # this share of the fish's peak contrast (0: the outline's end) ... 0.4 until
                       # 2026-12-07: a body paler towards its tail than at its head was cut short
                       # there (tuning tanks 7000-7039, both ends right in both views 146 -> 154;
                       # bench 90 tanks recall 0.377 / 0.441 -> 0.382 / 0.452, precision 0.880 /
                       # 0.896 -> 0.894 / 0.890; drawn fish 399 and 347 -> 399 and 346 right)
PEDUNCLE_DROP = 0.6    # ... or below this share of the most it had over the 5 % of the length behind
FIN_PAST_FORK = 0.09   # a dark run followed past the fork by more than this share of the body is a fin
                       # (_runs_past_fork): on the bench's tanks (1000-1039) peduncles reached at most
                       # 0.065 past it; a fin as dark as the peduncle, its lobes 0.13 L past the fork, 0.13-0.15
DARK_FIN_REACH = 0.01   # where a caudal fin as dark as the body runs on from the body's end, a body end
                        # found otherwise (vision.surface_nets) is not taken further out than this
                        # share of the length: the learned locator, trained on the renderer's thin
                        # peduncles, took such a fin (the tests' drawn fish, after an outside tester's) for body
N_MID = 15         # midline points: the fish's 3-D line is fitted to them (5 -> 15: 3-D recall x1.3 on the bench)


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


def _notches(r: Region, centre, e, n, lo, L, tmid):
    """Deepest fork notch at each end ((depth / L, point or None), low end then high end): in the
    body's outline when the caudal fin was dark enough to join it (drawn at the higher level, the
    notch is less filled in by blur), else in the outline with the pale fin."""
    best = [(0.0, None), (0.0, None)]
    for outline in (r.contour, r.outline):
        s_o, t_o = (outline - centre) @ e, (outline - centre) @ n
        ko = np.clip(((s_o - lo) / L * N_SLICES).astype(int), 0, N_SLICES - 1)
        found = _ends_defects(outline, s_o, t_o - tmid[ko], L, float(s_o.min()), float(s_o.max()))
        for end, (depth, i) in enumerate(found):
            if best[end][1] is None and i >= 0:
                best[end] = (depth, outline[i].astype(float))
    return best


def _extreme(contour: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Tip of the outline along a direction: the mean of the points within 0.75 px of the extreme
    (a blunt snout's tip is its middle), pushed out to the extreme."""
    proj = contour @ direction
    top = proj.max()
    near = contour[proj >= top - 0.75]
    tip = near.mean(axis=0)
    return tip + (top - tip @ direction) * direction


@dataclass
class _AlongTail:
    """The silhouette's (``Region.whole``) contrast by px along the tail from the snout, shared by
    the body-end checks: each pixel's bin (behind the snout: bin 0), contrast (>= 0) and offset
    across (px, to the tail's left), and the contrast summed per bin."""

    bin: np.ndarray      # (P,) int
    w: np.ndarray        # (P,) float32
    across: np.ndarray   # (P,) float
    mass: np.ndarray     # (B,) float


def _along_tail(r: Region, snout: np.ndarray, tail: np.ndarray) -> _AlongTail:
    ys, xs = np.nonzero(r.whole)
    w = np.clip(r.con[ys, xs], 0, None)
    rel = np.c_[xs, ys] + r.origin - snout
    b = np.clip(np.round(rel @ tail).astype(int), 0, None)
    return _AlongTail(b, w, rel @ np.array([-tail[1], tail[0]]), np.bincount(b, weights=w))


def _fin_base(r: Region, prof: _AlongTail, snout: np.ndarray, tail: np.ndarray, level: float = 0.16
              ) -> np.ndarray:
    """The caudal fin's base by mass: going from the snout towards the tail, the last place where the
    fish's contrast summed across the body (its "mass" per pixel of length) is still ``level`` of
    the body's most (a peduncle keeps ~15-25 % of the widest slice's mass, a fin seen edge-on less).
    Used as a check on the outline's own end, which runs on along a caudal fin dark enough to pass
    the outline's level (the outline's end alone, measured on renders, was the better estimate
    otherwise)."""
    mass = np.convolve(prof.mass, np.ones(3) / 3, mode="same")
    top = mass.max(initial=0)
    above = np.flatnonzero(mass >= level * top)
    if top <= 0 or len(above) == 0:
        return _extreme(r.contour, tail)
    j = int(above[-1])
    nxt = mass[j + 1] if j + 1 < len(mass) else 0.0
    frac = (mass[j] - level * top) / max(mass[j] - nxt, 1e-9)      # where the fall crosses the level
    along = j + float(np.clip(frac, 0, 1))
    at = prof.bin == j
    lateral = float((prof.w[at] * prof.across[at]).sum() / max(prof.w[at].sum(), 1e-9))
    return snout + along * tail + lateral * np.array([-tail[1], tail[0]])


# A caudal fin seen edge-on as a dark line (``_fin_line_start``, 2026-12-07): the region's dark rear
# end at most FIN_LINE_WIDTH of the body's widest, of even width (within FIN_LINE_EVEN of its end's)
# for at least FIN_LINE_LENGTH of the length, and a step down from the body (the widest of the 4 %
# of the length before it at least FIN_LINE_STEP x the line's width). The renderer's peduncles are
# as thin and as even for up to ~0.14 of the length, but taper into it (no step); the tests' thin
# peduncle (tests/vision/test_surface.py) is even for 0.13. Measured: the tests' drawn edge-on fins
# (bench/diag_surface_drawn.py, 60 tanks, seeds 1000+ / 3000+) right 346 / 391 -> 378 / 409 and
# 331 / 390 -> 369 / 405 reported; renderer 90 tanks recall 0.382 / 0.452 -> 0.379 / 0.450 at
# precision 0.894 / 0.890 -> 0.893 / 0.893; tuning tanks' ends unchanged (154 both right)
FIN_LINE_WIDTH = 0.25
FIN_LINE_EVEN = 1.3
FIN_LINE_LENGTH = 0.16
FIN_LINE_STEP = 1.8


def _fin_line_start(r: Region, prof: _AlongTail, length: float) -> float | None:
    """Where a caudal fin standing edge-on as a dark line begins, in px along the tail from the
    snout, or None (see FIN_LINE_WIDTH). ``length``: the fish's, snout to body end, px. Widths are
    the contrast summed across the body over its most (px of full contrast) per px along it. A fin
    as dark as the body passes the mass and level tests a peduncle passes; its width does not taper."""
    if len(prof.bin) < 10:
        return None
    ridge = np.zeros(len(prof.mass), prof.w.dtype)  # of the contrast's own type: ufunc.at's fast path
    np.maximum.at(ridge, prof.bin, prof.w)
    width = np.convolve(prof.mass / np.maximum(ridge, 1e-6), np.ones(3) / 3, mode="same")
    dark = np.flatnonzero(ridge >= PEDUNCLE_LEVEL * r.peak)     # a pale fin beyond is no body
    if len(dark) == 0:
        return None
    end = int(dark[-1])
    tail_n = max(2, int(round(0.04 * length)))
    w_end = float(np.median(width[max(end - tail_n, 0):end + 1]))
    if w_end > FIN_LINE_WIDTH * float(width.max()):
        return None
    wider = np.flatnonzero(width[:end] > FIN_LINE_EVEN * w_end)
    j = int(wider[-1]) + 1 if len(wider) else 0
    if end - j < FIN_LINE_LENGTH * length or j < tail_n:
        return None
    # a peduncle narrows gradually into its even end; a fin's base is a step down from the body
    return float(j) if float(width[j - tail_n:j].max()) >= FIN_LINE_STEP * w_end else None


def _peduncle_end(r: Region, base: np.ndarray, tail: np.ndarray, length: float, level: float) -> np.ndarray:
    """The body's rear end past ``base`` along a caudal peduncle too thin for the outline: the body
    narrows to a few pixels there and blur takes its edge below the outline's level, while its
    ridge (the most contrast across it) stays at ~0.45-0.7 of the fish's peak up to the fin base,
    where it drops within a few per cent of the length to the pale, edge-on fin (~0-0.35; measured
    on rendered tanks, seeds 7000+). Followed straight on along the tail, up to a quarter of the
    length, to where the ridge falls below ``level`` of the peak or below PEDUNCLE_DROP of the ridge
    just behind (a fin paler than the body but above the level still ends the body); ``base`` when
    the ridge already has."""
    side = np.array([-tail[1], tail[0]])
    half = max(2.0, 0.04 * length)
    step = 0.5
    back = int(np.ceil(0.05 * length / step))            # the ridge just behind, for the drop
    along = np.arange(-back, int(0.25 * length / step)) * step
    across = np.arange(-half, half + 0.5, 1.0)
    grid = base - r.origin + along[:, None, None] * tail + across[None, :, None] * side
    ridge = cv2.remap(r.con, grid[..., 0].astype(np.float32), grid[..., 1].astype(np.float32),
                      cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0).max(axis=1)
    behind = np.lib.stride_tricks.sliding_window_view(ridge, back).max(axis=1)[:len(ridge) - back]
    floor = np.maximum(level * r.peak, PEDUNCLE_DROP * behind)      # for samples back, back + 1, ...
    below = np.flatnonzero(ridge[back:] < floor)
    if len(below) == 0 or below[0] == 0:
        return base
    j = back + int(below[0])              # the ridge crosses the floor between samples j - 1 and j
    f = floor[j - back]
    frac = (ridge[j - 1] - f) / max(ridge[j - 1] - ridge[j], 1e-9)
    return base + (along[j - 1] + step * float(np.clip(frac, 0.0, 1.0))) * tail


def _runs_past_fork(snout, base, end, base_ratio: float | None, tail: np.ndarray) -> bool:
    """Whether the dark run ``_peduncle_end`` followed on from the body's end to ``end`` is the
    caudal fin, not a peduncle: it reaches further than FIN_PAST_FORK of the body past the fork the
    species' ratio places from ``base``. A peduncle ends at the fin's base, short of the fork; an
    edge-on fin as dark as the peduncle runs on past the fork to its lobes' tips, and taken for body
    its tip became the "fin base" and the fork was placed a fin's length further (a fish 1.33 x its
    length). Ridge, width and darkness do not tell the two apart: on the bench's renders and such a
    fin, its ridge 0.56-0.74 of the body's just before it and its width 0.22-0.36 of the body's there
    overlap the peduncles' 0.53-0.99 and 0.36-1.1. Without a ratio the rear point is the fin's end
    anyway: never."""
    if base_ratio is None:
        return False
    body = float(np.linalg.norm(base - snout))
    return float((end - base) @ tail) > (1 / base_ratio - 1 + FIN_PAST_FORK) * body


def _fork(snout, base, tip, notch, base_ratio: float | None, tail: np.ndarray) -> np.ndarray:
    """The fork point from what the view shows. A notch seen in the fin is the fork, unless the
    species' fin-base ratio puts the fork more than 4 % of the length away from it (a bite out of
    the outline, not the fork) -- unless the body's outline ends where the fin does, past the
    notch (a caudal fin dark enough to join the body: no fin base seen), when the notch is kept.
    Without a notch: on from the fin base by the species' ratio along
    the body's direction at the tail (the faint fin's own direction, tried, was noisier); without
    a ratio, the rear end of the fin (fork length = total)."""
    est = None
    if base_ratio is not None:
        run = np.linalg.norm(base - snout) * (1 / base_ratio - 1)
        est = base + run * tail
    if notch is not None and (est is None or np.linalg.norm(notch - est) < 0.04 * np.linalg.norm(est - snout)):
        return notch
    body = np.linalg.norm(base - snout)
    if notch is not None and (tip - base) @ tail < 0.05 * body and (notch - base) @ tail < 0:
        return notch        # the body's outline runs out to the fin's tip, past the notch: a dark fin
    return est if est is not None else tip


def _on_fin(r: Region, point: np.ndarray, tail: np.ndarray, reach: float) -> np.ndarray:
    """A point placed on the caudal fin moved across the tail onto the fin's ridge, where the fin
    shows as a faint line (seen edge-on from above): the ridge is what both views see, the
    extrapolated point is not. Unchanged when no ridge stands out within +-``reach`` px."""
    side = np.array([-tail[1], tail[0]])
    across = np.arange(-np.ceil(reach), np.ceil(reach) + 1)
    along = np.arange(-2.0, 3.0)
    grid = point - r.origin + along[:, None, None] * tail + across[None, :, None] * side
    prof = cv2.remap(r.con, grid[..., 0].astype(np.float32), grid[..., 1].astype(np.float32),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).mean(axis=0)
    j = int(np.argmax(prof))
    edge = np.r_[prof[:2], prof[-2:]].mean()
    if not (0 < j < len(prof) - 1) or prof[j] - edge < 0.1 * r.peak:
        return point
    den = prof[j - 1] - 2 * prof[j] + prof[j + 1]
    off = 0.5 * (prof[j - 1] - prof[j + 1]) / den if den < 0 else 0.0
    return point + (across[j] + float(np.clip(off, -0.5, 0.5))) * side


def _body_end(r: Region, prof: _AlongTail, snout: np.ndarray, tail_dir: np.ndarray, L: float,
              base_ratio: float | None) -> tuple[np.ndarray, bool]:
    """The body's rear end (the caudal fin's base) from the region: the outline's end, unless it
    ran on along a dark fin (by mass), followed on along a thin peduncle; and whether a caudal fin
    as dark as the body was seen running on from it (by mass, or followed past the fork)."""
    base = _extreme(r.contour, tail_dir)
    by_mass = _fin_base(r, prof, snout, tail_dir)
    dark_fin = bool((base - by_mass) @ tail_dir > 0.05 * np.linalg.norm(base - snout))
    if dark_fin:
        base = by_mass                # the outline ran on along a dark caudal fin
    if PEDUNCLE_LEVEL > 0:
        followed = _peduncle_end(r, base, tail_dir, L, PEDUNCLE_LEVEL)
        if not _runs_past_fork(snout, base, followed, base_ratio, tail_dir):
            base = followed           # (else what it followed was a caudal fin as dark as the peduncle)
        else:
            dark_fin = True
    return base, dark_fin


def analyse(r: Region, base_ratio: float | None = None, snout_at: np.ndarray | None = None,
            base_at: np.ndarray | None = None) -> Fish2D | None:
    """Front/rear/intermediate points of one region; None if it is not fish-shaped. ``base_ratio``:
    the species' caudal fin base / fork length (``FishGeometry.fin_base_to_fork``). ``snout_at``,
    ``base_at`` (2,) px: the snout tip and the body's rear end found otherwise (``vision.surface_nets``),
    taken instead of the outline's; the fork and midline follow from them."""
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
    s_c = (r.contour - centre) @ e
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
    (d_lo, i_lo), (d_hi, i_hi) = _notches(r, centre, e, n, lo, L, tmid)
    band = slice(int(0.15 * N_SLICES), int(0.45 * N_SLICES) + 1)
    w_lo, w_hi = width[band].mean(), width[::-1][band].mean()
    taper = (w_hi - w_lo) / max(w_hi + w_lo, 1e-9)
    s_o = (r.outline - centre) @ e            # the pale caudal fin runs on past the body's tail end
    fin = (float(lo - s_o.min()) - float(s_o.max() - hi)) / L
    evidence = 6.0 * taper + 25.0 * (d_lo - d_hi) + 20.0 * fin
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
    if snout_at is not None:
        snout = np.asarray(snout_at, float)
    prof = _along_tail(r, snout, tail_dir)
    base, dark_fin = _body_end(r, prof, snout, tail_dir, L, base_ratio)
    if base_at is not None and not (dark_fin and (np.asarray(base_at) - base) @ tail_dir > DARK_FIN_REACH * L):
        base = np.asarray(base_at, float)
    # a body's end on a dark edge-on fin (by mass, followed, or the learned locator's) goes back to its base
    line = _fin_line_start(r, prof, float(np.linalg.norm(base - snout)))
    if line is not None and (base - snout) @ tail_dir > line + 0.01 * L:
        base = base - ((base - snout) @ tail_dir - line) * tail_dir
    tip = _extreme(r.outline, tail_dir)
    notch = fork_i if fork_d > 0 else None
    fork = _fork(snout, base, tip, notch, base_ratio, tail_dir)
    if notch is None or not np.array_equal(fork, notch):
        fork = _on_fin(r, fork, tail_dir, 0.06 * np.linalg.norm(fork - snout))
    fr = np.linspace(0, 1, N_MID + 2)[1:-1]
    s0 = (snout - centre) @ e                  # intermediate points between the snout and the body's
    s1 = (base - centre) @ e                   # end, or the fork when the "end" ran on along a dark fin
    s1 = s0 + np.sign(s1 - s0) * min(abs(s1 - s0), abs((fork - centre) @ e - s0))
    s_f = s0 + fr * (s1 - s0)
    t_f = np.interp(s_f, centres, tmid)
    mid = centre + s_f[:, None] * e + t_f[:, None] * n
    return Fish2D(snout, fork, mid, float(np.linalg.norm(snout - fork)), float(width.max()), head_conf,
                  fork_d, float(elong), r.glare, r.peak, base, tip, notch,
                  bool(notch is not None and np.array_equal(fork, notch)), centre)
