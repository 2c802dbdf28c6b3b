"""The fork's innermost point, located at full resolution near a fin candidate.

A candidate from the template bank is good to a pixel of its pyramid level and ~11 degrees of angle;
fork length must be ~1 % accurate, so each candidate is re-measured on the image itself (or the
pyramid level whose pixel matches the fin's size, so big fins cost no more than small ones).

In the candidate's own frame (x towards the head, y across) the notch is water between two inner
lobe edges meeting at the innermost point. Fish and water levels are the medians just ahead of the
candidate (the caudal peduncle) and behind it on the axis (always water, between or past the
lobes); each row across the axis is scanned from the back for its first crossing of the mid level
(sub-pixel, linear). Those crossings trace a V: the two inner edges. A straight line is fitted to
each arm (the rows next to the apex are left out: blur rounds the apex off and pulls it back), and
their intersection is the innermost point; the bisector of the arms is the fin's axis. No V (a
straight edge, a convex corner, a flat patch) means no fork: the candidate is dropped, unless the
rows traced again from inside the fin back to the first water (clutter behind the tail crosses the
mid level first when scanned from the back) show one (``INSIDE_FROM``).

Where it fails (measured 2026-12-02 on bench/bench_survey_underwater.py's renderer, seeds 0-29:
the 110 views of fully visible fish, each started on its true fork and axis, span 0.3 of its
length): one pass shows a fork in 82 and puts 64 within 3 % of the length; the survey's second
pass, from there, 73 and 60. Of the 50 views not within 3 %: 28 show no fork in the first pass, 9
lose it in the second, 13 are placed > 3 % off. By what is behind the fin: reef 24 of 42 views
fail, net 11 of 22, open water 15 of 46 -- the mid level between the peduncle's colour and the
water's is crossed by the reef's pattern and the net's bars as well as by the fin's edge; 13 of the
50 have a fin-to-water contrast under 12 grey levels (a faint fin behind a net or in dim water).
In crops of the sampled grids, the other failures are sea bream and sea bass fins whose lobes
reach the grid's edge (their span is ~0.34 of the length, not 0.3), and a few rows of one arm
crossing early on a speck or a ray seen through the fin, which turns that arm's least-squares line.
Measured and left out (each locates a few more forks; in the survey each adds wrong reports, see
``vision.underwater``): each arm fitted again without its outlying rows (from true starts 60 -> 62
within 3 %; from starts 4 % and ~6 degrees off, 43 -> 46); a grid 0.75x the span tried where the
first shows no fork (one pass from true starts: 64 -> 73 within 3 %, the fork stage ~1.4x).
Along the axis (bench/diag_length_bias.py): unbiased on a V notch drawn with exact coverage (+0.1
px at 45-70 px fish, tests/vision/test_fork_subpixel.py); behind the renderer's notch, whose edges
close into a slit (x ~ |y|^0.77), by +0.6 / +0.9 / +1.0 px for fish of 40-80 / 80-160 / 160-320 px
drawn with their coverage. Fitting whichever apex power fits best (no preference for a V) halves
that but cost precision on the survey bench (seeds 1000+: 0.957 -> 0.929).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vision.fins import Fins, half, sample_frames_raw

SAMPLES = 40            # grid steps per fin span
SHALLOW_SLOPE = 0.12    # arms flatter than this: a square-cut or shallow tail
APEX_BEHIND = 0.0      # how far (spans) the fitted apex may lie behind the deepest crossing seen
FLAT_OK = True
# a candidate that shows no fork is traced again from inside the fin: each row from this far ahead
# of the candidate (spans) back to its first water, and kept only if its arms fit within
# INSIDE_RMS spans (without that limit it located ~40 % more forks in the survey, mostly on clutter:
# a ragged fit). Started on true rendered forks (seeds 0-29 / 1000-1029), 50 -> 55 % / 61 -> 66 %
# are located within 3 % of the length; from starts ~5 % and ~8 degrees off, 40 -> 44 % / 52 -> 57 %.
# Rows the fin does not reach at the start taken from inside only: more located from true starts
# (67 %) but a worse survey (seeds 0+: precision 0.966 -> 0.932).
INSIDE_FROM = 0.15
INSIDE_RMS = 0.02





@dataclass
class Forks:
    """Located forks (rows align with the input candidates; ``ok`` says which are forks)."""

    fins: Fins              # refined xy, angle; polarity from the measured levels
    ok: np.ndarray          # (N,) bool
    fish_level: np.ndarray  # (N, C) colour (grey: C = 1) ahead of the fork
    water_level: np.ndarray # (N, C) colour behind it
    arm_rms: np.ndarray     # (N,) RMS residual of the arm fits, in fin spans
    contrast: np.ndarray    # (N,) |fish - water| colour distance


def pyramid(img: np.ndarray, levels: int = 5) -> list[np.ndarray]:
    """Gaussian pyramid (grey or colour, the image's own dtype: uint8 is fastest to sample)."""
    out = [np.asarray(img)]
    for _ in range(levels - 1):
        if min(out[-1].shape[:2]) < 16:
            break
        out.append(half(out[-1]))
    return out


def nan_median(a: np.ndarray) -> np.ndarray:
    """Median over all but the first axis, ignoring NaN (NaN where all are); np.nanmedian's masked
    arrays cost ~100x more."""
    a = np.sort(a.reshape(len(a), -1), axis=1)                     # NaN sort last
    n = (~np.isnan(a)).sum(axis=1)
    return np.where(n > 0, a[np.arange(len(a)), np.maximum(n - 1, 0) // 2], np.nan)


def _line_fit(y: np.ndarray, x: np.ndarray, w: np.ndarray):
    """Weighted least-squares x = a + b y per row (N, M) -> a, b, rms."""
    sw = w.sum(axis=1)
    my = (w * y).sum(axis=1) / np.maximum(sw, 1e-9)
    mx = (w * x).sum(axis=1) / np.maximum(sw, 1e-9)
    dy = y - my[:, None]
    b = (w * dy * (x - mx[:, None])).sum(axis=1) / np.maximum((w * dy * dy).sum(axis=1), 1e-9)
    a = mx - b * my
    res = x - (a[:, None] + b[:, None] * y)
    rms = np.sqrt((w * res * res).sum(axis=1) / np.maximum(sw, 1e-9))
    return a, b, rms


POWERS = np.array([0.75, 1.0, 1.5])
# another power must beat a V's misfit by this factor. 2.0 (halve it) before 2026-12-03: 1.2 moves
# the grow-out's 640x480 forks 0.05-0.13 px nearer the rendered notch (0.66 -> 0.59 px behind it at
# 40-60 px fish; bench/diag_growout_survey.py, seeds 200000+), the underwater bench unchanged (seeds
# 0+ and 1000+, to three decimals); 1.0 (no preference) places a drawn V notch's apex 1.3 px off in
# one view (tests/vision/test_underwater.py, a fish +1.86 % long).
PREFER_V = np.where(POWERS == 1.0, 1.0, 1.2)


def _fit_powers(r: np.ndarray, x: np.ndarray, wf: np.ndarray):
    """Weighted least squares x = x0 + slope r for every power's r (N, P, rows): x0, slope, rms."""
    sw = np.maximum(wf.sum(axis=2), 1e-9)
    mr = (wf * r).sum(axis=2) / sw
    mx = (wf * x).sum(axis=2) / sw
    dr = r - mr[..., None]
    slope = (wf * dr * (x - mx[..., None])).sum(axis=2) / np.maximum((wf * dr * dr).sum(axis=2), 1e-12)
    x0 = mx - slope * mr
    res = x - x0[..., None] - slope[..., None] * r
    return x0, slope, res


def _apex(y: np.ndarray, x: np.ndarray, w: np.ndarray, y0: np.ndarray, xmax: np.ndarray) -> np.ndarray:
    """Innermost point x0 of notch edges x = x0 - c |y - y0|^p (N,), the power p that fits best:
    1 is a V, 2 a rounded U, < 1 a fork whose edges close into a slit that blur hides (the edge
    runs parallel to the axis at the apex). Rows next to the apex are already left out of ``w``;
    rows whose crossing misses the fitted curve by more than 3x the median miss (a ragged fin
    ray, a glint) are dropped and the fit repeated. The apex may not lie more than 0.1 span
    ahead of the deepest crossing seen, nor behind it (``APEX_BEHIND``): blur rounds the apex off
    and pulls its crossing back, so the innermost point is at least as deep as any crossing seen."""
    r = np.abs(y - y0[:, None])[:, None, :] ** POWERS[None, :, None]          # (N, P, rows)
    xx = np.broadcast_to(x[:, None, :], r.shape)
    wf = np.broadcast_to(w.astype(float)[:, None, :], r.shape)
    for _ in range(2):
        x0, slope, res = _fit_powers(r, xx, wf)
        miss = np.abs(res)
        med = _masked_median(miss, wf > 0)
        wf = (w[:, None, :] & (miss <= 3 * med[..., None] + 1e-4)).astype(float)
    x0, slope, res = _fit_powers(r, xx, wf)
    err = (wf * res * res).sum(axis=2) / np.maximum(wf.sum(axis=2), 1)
    best = (err * PREFER_V).argmin(axis=1)
    apex = x0[np.arange(len(x0)), best]
    return np.clip(apex, xmax - APEX_BEHIND, xmax + 0.1)


def _masked_median(a: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Median of a over its last axis where m, per leading index (NaN-free sort trick)."""
    v = np.sort(np.where(m, a, np.inf), axis=-1)
    n = m.sum(axis=-1)
    idx = np.maximum(n - 1, 0) // 2
    return np.where(n > 0, np.take_along_axis(v, idx[..., None], axis=-1)[..., 0], 0.0)


# turned axes for a candidate that shows no fork along its own (opt-in, ``tries``). Started on the
# 38 true forks of underwater scenes 0-19 (then located again from the result): 18 -> 20 found
# from the true axis, 10 -> 20 from 20 degrees off. Not used by the survey: on the end hypotheses
# it finds 2 more forks per 38 in a view but no more fish in the bench (seeds 0-32, 60 fish: recall
# 0.083 either way) and costs 2-4x the fork stage (ratio 0.164 -> 0.28-0.35).
ANGLE_TRIES = np.radians([10.0, -10.0, 20.0, -20.0])


def locate_forks(pyr: list[np.ndarray], fins: Fins, min_contrast: float = 5.0, min_slope: float = 0.12,
                 flat_ok: bool = FLAT_OK, tries=(), retry: np.ndarray | None = None) -> Forks:
    """Re-measure every candidate's innermost fork point and axis on the image pyramid; a candidate
    that shows no fork along its own axis (and is in ``retry``, default all) is measured again along
    each axis turned by ``tries`` (the first that shows one is kept): a proposal's axis can be 20
    degrees off, and then one lobe leaves the grid's rows."""
    out = _locate(pyr, fins, min_contrast, min_slope, flat_ok)
    for turn in tries:
        bad = np.flatnonzero(~out.ok if retry is None else ~out.ok & retry)
        if len(bad) == 0:
            break
        sub = fins.take(bad)
        sub = Fins(sub.xy, sub.angle + turn, sub.span_px, sub.score, sub.polarity, sub.body)
        again = _locate(pyr, sub, min_contrast, min_slope, flat_ok)
        hit = bad[again.ok]
        if len(hit) == 0:
            continue
        k = np.flatnonzero(again.ok)
        out.fins.xy[hit] = again.fins.xy[k]
        out.fins.angle[hit] = again.fins.angle[k]
        out.fins.polarity[hit] = again.fins.polarity[k]
        out.ok[hit] = True
        out.fish_level[hit] = again.fish_level[k]
        out.water_level[hit] = again.water_level[k]
        out.arm_rms[hit] = again.arm_rms[k]
        out.contrast[hit] = again.contrast[k]
    return out


def _locate(pyr: list[np.ndarray], fins: Fins, min_contrast: float, min_slope: float, flat_ok: bool) -> Forks:
    """One measurement of every candidate along its own axis."""
    N = len(fins)
    if N == 0:
        z = np.zeros(0)
        C = pyr[0].shape[2] if pyr[0].ndim == 3 else 1
        return Forks(fins, np.zeros(0, bool), np.zeros((0, C)), np.zeros((0, C)), z, z.copy())
    t = np.linspace(-0.6, 0.6, int(1.2 * SAMPLES) + 1)              # in spans
    S = fins.span_px
    g = S / SAMPLES
    axes = np.column_stack((np.cos(fins.angle), np.sin(fins.angle)))
    C = pyr[0].shape[2] if pyr[0].ndim == 3 else 1
    lev = np.clip(np.floor(np.log2(np.maximum(g, 1.0))).astype(int), 0, len(pyr) - 1)
    ahead = (t >= 0.1) & (t <= 0.35)
    behind = t <= -0.35
    near = np.abs(t) <= 0.1
    # levels as the samples' own float32 medians, s summed in float64 from float32 terms: the
    # arithmetic of the grids' first form, so that samples at the mid level fall on the same side
    fish, water = np.empty((N, C), np.float32), np.empty((N, C), np.float32)
    s = np.empty((N, len(t), len(t)))
    for k in np.unique(lev):                                     # every candidate is at one level
        idx = np.flatnonzero(lev == k)
        f = 2.0 ** -k
        off = t[None] * (S[idx] * f)[:, None]
        # the samples as remap gives them (uint8: no float copy of the grids), NaN only where used
        P, out = sample_frames_raw(pyr[k], (fins.xy[idx] + 0.5) * f - 0.5, axes[idx], off, off)
        P = P.reshape(len(idx), len(t), len(t), C)
        Pn = P[:, near].astype(np.float32)
        if out is not None:
            Pn[out[:, near]] = np.nan
        fk = np.stack([nan_median(Pn[:, :, ahead, c]) for c in range(C)], axis=1)
        wk = np.stack([nan_median(Pn[:, :, behind, c]) for c in range(C)], axis=1)
        fish[idx], water[idx] = fk, wk
        d = fk - wk
        # each sample's position between the water's colour (-0.5) and the fish's (+0.5)
        unit = d / np.maximum(np.linalg.norm(d, axis=1), 1e-6)[:, None] ** 2
        sk = np.empty(P.shape[:3])
        tmp = np.empty(P.shape[:3], np.float32)
        for c in range(C):                         # channel by channel: no (N, y, x, C) float copy
            np.subtract(P[..., c], wk[:, c, None, None], out=tmp)
            tmp *= unit[:, c, None, None]
            if c == 0:
                sk[...] = tmp                      # (0 + the first term: exactly the first term)
            else:
                np.add(sk, tmp, out=sk, dtype=np.float64)
        sk -= 0.5                                                              # fish > 0
        if out is not None:
            sk[out] = np.nan
        s[idx] = sk
    diff = fish - water
    contrast = np.linalg.norm(diff, axis=1)
    sign = np.sign(diff.sum(axis=1))
    ok = np.zeros(N, bool)
    xy, ang, rms = fins.xy.copy(), fins.angle.copy(), np.zeros(N)
    # a candidate without the contrast is no fork whatever its outline: only the others are traced
    # (rows are independent, so tracing a subset gives those rows exactly what tracing all would)
    live = np.flatnonzero(contrast >= min_contrast)
    if len(live):
        ok_l, xy[live], ang[live], rms[live] = _trace(s, live, t, fins.take(live), contrast[live], min_contrast,
                                                      min_slope, flat_ok)
        ok[live] = ok_l
    out = Fins(np.where(ok[:, None], xy, fins.xy), np.where(ok, ang, fins.angle),
               fins.span_px, fins.score, np.where(ok, sign, fins.polarity), fins.body)
    return Forks(out, ok, fish, water, rms, contrast)


def _trace(s: np.ndarray, which: np.ndarray, t: np.ndarray, fins: Fins, contrast: np.ndarray, min_contrast: float,
           min_slope: float, flat_ok: bool):
    """Each row's crossing into the fish (``s`` (M, rows, samples) > 0; the candidates are its
    rows ``which`` (N,): no copy of their grids) and the notch they trace (``_notch``), from the
    back and, for candidates that show no fork that way, from inside the fin: ok, xy, angle, rms (N,)."""
    inside = s >= 0
    nan_row = np.isnan(s).any(axis=2)
    if len(which) < len(s):
        inside, nan_row = inside[which], nan_row[which]
    first = inside.argmax(axis=2)                                          # (N, rows)
    has = inside.any(axis=2) & (first > 0) & ~nan_row
    ok, xy, ang, rms = _notch(s, t, first, has, fins, contrast, min_contrast, min_slope, flat_ok, which)
    if INSIDE_FROM is not None and not ok.all():
        # clutter behind the fin (reef, another fish) crosses the mid level before the fin's edge
        # does: the rows of the candidates that showed no fork are traced again from inside the
        # fin (just ahead of the candidate) back to the first water, where that reaches water
        bad = np.flatnonzero(~ok)
        j0 = int(np.searchsorted(t, INSIDE_FROM))
        out = ~inside[bad, :, : j0 + 1]
        blocked = np.flip(np.logical_or.accumulate(np.flip(out, axis=2), axis=2), axis=2)
        first_in = (~blocked).argmax(axis=2)
        has_in = ~blocked[..., j0] & (first_in > 0) & ~nan_row[bad]
        # (rows the fin does not reach at that point keep their crossing from the back)
        ok2, xy2, ang2, rms2 = _notch(s, t, np.where(has_in, first_in, first[bad]), has[bad] | has_in,
                                      fins.take(bad), contrast[bad], min_contrast, min_slope, flat_ok, which[bad])
        ok2 &= rms2 <= INSIDE_RMS
        hit = bad[ok2]
        ok[hit], xy[hit], ang[hit], rms[hit] = True, xy2[ok2], ang2[ok2], rms2[ok2]
    return ok, xy, ang, rms


def _notch(s: np.ndarray, t: np.ndarray, first: np.ndarray, has: np.ndarray, fins: Fins, contrast: np.ndarray,
           min_contrast: float, min_slope: float, flat_ok: bool, which: np.ndarray | None = None):
    """The notch from each row's crossing into the fish (``first``: the sample past it, ``has``:
    the row has one): ok (N,), the innermost point xy (N, 2), the fin's axis angle (N,), the arm
    fits' RMS (N,) in spans. ``which``: the rows of ``s`` these candidates are (default all)."""
    N = len(fins)
    S = fins.span_px
    axes = np.column_stack((np.cos(fins.angle), np.sin(fins.angle)))
    j = np.clip(first, 1, len(t) - 1)
    n = np.arange(len(s))[:, None] if which is None else np.asarray(which)[:, None]
    r = np.arange(s.shape[1])[None]
    s0, s1 = s[n, r, j - 1], s[n, r, j]                  # gathered: no copy of the candidates' grids
    with np.errstate(invalid="ignore", divide="ignore"):
        xb = t[j - 1] + (t[1] - t[0]) * (-s0) / (s1 - s0)                   # crossing, in spans
    rows = np.abs(t) <= 0.45
    # past the lobes' tips (rows beyond ~half a span each side) a tail has water as far ahead as
    # the grid reaches, or the body well ahead of the notch; a straight edge goes on
    outer = np.where(has & np.isfinite(xb), xb, np.inf)
    side_hi = outer[:, t >= 0.57].min(axis=1)
    side_lo = outer[:, t <= -0.57].min(axis=1)
    xb = np.where(has & rows[None], xb, -np.inf)
    # the apex is near the candidate: rows far out can pass beside the fin and meet the body
    apex = np.where(np.abs(t) <= 0.12, xb, -np.inf).argmax(axis=1)
    y0 = t[apex]
    dy = t[None] - y0[:, None]
    valid = np.isfinite(xb)
    xbf = np.where(valid, xb, 0.0)
    gap = 2.5 / SAMPLES
    up = valid & (dy > gap) & (dy <= 0.25)
    dn = valid & (dy < -gap) & (dy >= -0.25)
    a1, b1, r1 = _line_fit(np.broadcast_to(t, xb.shape), xbf, up.astype(float))
    a2, b2, r2 = _line_fit(np.broadcast_to(t, xb.shape), xbf, dn.astype(float))
    # one lobe's inner edge may be faint or short (few rows cross the mid level): 2 rows on that
    # side are enough when the other gives the rest
    nu, nd = up.sum(axis=1), dn.sum(axis=1)
    enough = (np.minimum(nu, nd) >= 2) & (nu + nd >= 6)
    v_shape = (b1 < -min_slope) & (b2 > min_slope)
    if flat_ok:
        xm = xb[np.arange(N), np.where(np.abs(t) <= 0.12, xb, -np.inf).argmax(axis=1)]
        bounded = (side_hi > xm + 0.1) | (side_lo > xm + 0.1)
        v_shape |= (b1 < SHALLOW_SLOPE) & (b2 > -SHALLOW_SLOPE) & (contrast >= 2 * min_contrast) & bounded
    with np.errstate(invalid="ignore", divide="ignore"):
        yv = (a2 - a1) / (b1 - b2)
    # a shallow or square-cut tail (tilapia, worn fins): the arms barely meet; the apex row is
    # where the rear edge is innermost
    shallow = ~(np.abs(b1 - b2) >= 2 * SHALLOW_SLOPE) | ~np.isfinite(yv)
    yv = np.where(shallow, y0, yv)
    xmax = xb[np.arange(N), apex]

    ok = (contrast >= min_contrast) & enough & v_shape & (np.abs(yv) < 0.45)
    # the apex only where the rest says fork (rows are independent: the same figures as for all)
    xv = np.full(N, np.nan)
    k = np.flatnonzero(ok)
    if len(k):
        xv[k] = _apex(np.broadcast_to(t, (len(k), len(t))), xbf[k], (up | dn)[k],
                      np.where(np.isfinite(yv), yv, y0)[k], xmax[k])
    ok &= np.isfinite(xv)

    # bisector of the arms, pointing back into the notch; the axis is its opposite
    d1 = np.column_stack((b1, np.ones(N))) / np.hypot(b1, 1)[:, None]
    d2 = np.column_stack((-b2, -np.ones(N))) / np.hypot(b2, 1)[:, None]
    back = d1 + d2
    back /= np.maximum(np.linalg.norm(back, axis=1), 1e-9)[:, None]
    normal = np.column_stack((-axes[:, 1], axes[:, 0]))
    new_axis = -(back[:, :1] * axes + back[:, 1:] * normal)
    with np.errstate(invalid="ignore"):
        xy = fins.xy + (xv * S)[:, None] * axes + (yv * S)[:, None] * normal
    ok &= np.all(np.isfinite(xy), axis=1)
    return ok, xy, np.arctan2(new_axis[:, 1], new_axis[:, 0]), np.maximum(r1, r2)
