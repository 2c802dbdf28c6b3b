"""Caudal fins (paper section 4.2.1): the emboss high-pass filter and a bank of fork templates over
angles and scales (eq. 13), evaluated where forks can be; shared frame sampling.

Eq. (13) is f_o(x, y) = max_i sum template_i . f*(x + xt, y + yt) over the emboss-filtered image f*.
Each template here is a fish's tail end drawn at one angle, size and fork depth (``fork_mask``:
peduncle, half-transparent fin, notch) and passed through the same emboss kernel, so it matches the
transitions a fork leaves in the filtered image (a matched filter). The sum is normalised (zero-mean
NCC): a fin in dim water scores as high as one in sunlit water. The bank is scored through its
principal components (a rotated template is a mix of a few fixed filters).

Where the bank runs. Over a whole frame (every pixel of a pyramid level, 16 angles x 2 sizes x
2 notches) it ranks the true fork of a fully visible rendered fish among its 80 best peaks for fewer
than a third of the fish (25 scenes, bench/bench_survey_underwater.py's renderer): a faint fin
beside the body's strong edges, reef texture and other fish is a weak pattern on its own. So forks
are proposed from the bodies (``vision.bodies``), located on the image (``vision.fork``), and the
bank is evaluated there, at the located fork's own angle and scale (``fin_scores``): a measure of
how fork-like the point is, one term of the fish's score. That is also cheaper than any pyramid
scan: a few dozen windows per image.

As a second proposer beside the bodies' ends (``bank_proposals``: the bank over the water-distance
working image and its halving, grid step 2, the 10 % of points with the most emboss energy, the
best 10 peaks at 1280x960, each through the full-resolution locator) it adds a few fish: bench
(107 scenes, 203 fish) recall 0.118 -> 0.133, precision 0.963 -> 0.967, ~15 ms a pair; seeds
1000+ 0.100 -> 0.105. Larger banks did not pay: every grid point (stride 1, 4 levels, 20 peaks)
located 19 instead of 16 of 76 true forks on 20 scenes but added ~45 ms a pair and false pairings;
each peak also tried at +-12 degrees, or only peaks with the body's region ahead, found no more.
The bank's best few peaks are rarely forks (reef, net and body edges); the locator, not the
proposals, is where most fish are lost (17 of 38 true forks located even when started on them).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vision import order_stats

# the emboss kernel, zero-sum (a pure high-pass): a directional derivative along the diagonal
EMBOSS = np.array([[-1, -1, 0], [-1, 0, 1], [0, 1, 1]], dtype=np.float32)

TEMPLATE_PX = 15
SPAN_OF_FL = 0.3            # caudal-fin span / fork length (sea bream ~0.3, salmon ~0.25)


@dataclass
class Fins:
    """Fork candidates in one image (N rows), full-resolution pixels."""

    xy: np.ndarray          # (N, 2) the fork's innermost point
    angle: np.ndarray       # (N,) rad, image direction from the fork towards the head (atan2(dv, du))
    span_px: np.ndarray     # (N,) fin span (height of the tail) in px
    score: np.ndarray       # (N,) |NCC| of the best template, 0..1
    polarity: np.ndarray    # (N,) +1 fish brighter than the water, -1 darker
    body: np.ndarray | None = None   # (N,) rad, the body's own axis where its region gave one (NaN: not)

    def body_angle(self) -> np.ndarray:
        """The body's axis where known, else the fin's."""
        if self.body is None:
            return self.angle
        return np.where(np.isfinite(self.body), self.body, self.angle)

    def __len__(self) -> int:
        return len(self.xy)

    def take(self, idx) -> Fins:
        return Fins(self.xy[idx], self.angle[idx], self.span_px[idx], self.score[idx], self.polarity[idx],
                    None if self.body is None else self.body[idx])

    @staticmethod
    def empty() -> Fins:
        z = np.zeros(0)
        return Fins(np.zeros((0, 2)), z, z.copy(), z.copy(), z.copy())


def fork_mask(size: int, angle: float, length: float, notch: float = 0.08, fin_level: float = 0.6,
              oversample: int = 8) -> np.ndarray:
    """Anti-aliased picture (size, size) float32 of a fish's tail end: 1 body (caudal peduncle
    widening into the body), ``fin_level`` fin (fins are thin and let the water through), 0 water.
    The innermost fork point at the window centre, the head towards ``angle`` (rad, image u right,
    v down); ``length``: fork length in px (the window shows its last ~45 %); ``notch``: fork depth
    (lobe tips behind the innermost point) / length. Proportions: a generic farmed fish (peduncle
    ~0.1 of the length deep, fin span ~0.3)."""
    ped, span = 0.05, SPAN_OF_FL / 2
    body = [(0.12, ped), (0.2, ped * 1.4), (0.4, ped * 2.8), (0.4, -ped * 2.8), (0.2, -ped * 1.4), (0.12, -ped)]
    fin = [(0.14, ped * 0.9), (-notch, span), (-notch + 0.03, span * 0.9), (0.0, 0.0),
           (-notch + 0.03, -span * 0.9), (-notch, -span), (0.14, -ped * 0.9)]
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, s], [-s, c]])
    centre = (size - 1) / 2
    big = np.zeros((size * oversample, size * oversample), np.float32)
    for poly, value in ((fin, fin_level), (body, 1.0)):
        p = (np.array(poly) * length) @ rot
        q = np.round(((p + centre + 0.5) * oversample - 0.5) * 16).astype(np.int32)
        cv2.fillPoly(big, [q], value, lineType=cv2.LINE_AA, shift=4)
    return cv2.resize(big, (size, size), interpolation=cv2.INTER_AREA)


WINDOW_OF_FL = 0.45         # a template window shows this share of the fork length


_BINOMIAL = np.array([1, 4, 6, 4, 1], np.float32) / 16


def half(img: np.ndarray) -> np.ndarray:
    """The next pyramid level: Gaussian-smoothed (cv2.pyrDown's kernel) and halved by 2x2 means, so
    that its pixel j covers full pixels 2j and 2j+1 -- the (x + 0.5) / 2 - 0.5 every sampler here
    assumes. cv2.pyrDown keeps pixel 2j instead: half a pixel off per level (1.5 px at the fourth
    of the size), leftward and upward, so a fish and its mirror image were sampled differently (a
    fork or snout moved towards one end in one direction and the other end in the other)."""
    img = np.asarray(img)
    h, w = img.shape[:2]
    b = cv2.sepFilter2D(img, -1, _BINOMIAL, _BINOMIAL, borderType=cv2.BORDER_REFLECT_101)
    if h % 2 or w % 2:                            # odd sides: the last row / column repeated
        b = cv2.copyMakeBorder(b, 0, h % 2, 0, w % 2, cv2.BORDER_REPLICATE)
    return cv2.resize(b, ((w + 1) // 2, (h + 1) // 2), interpolation=cv2.INTER_AREA)


def emboss(img: np.ndarray) -> np.ndarray:
    return cv2.filter2D(np.asarray(img, np.float32), cv2.CV_32F, EMBOSS, borderType=cv2.BORDER_REFLECT)


@dataclass(frozen=True)
class Bank:
    """Unit, zero-mean emboss templates (T, size*size) with their angle and span (px)."""

    vectors: np.ndarray
    angle: np.ndarray
    span: np.ndarray
    size: int
    basis: np.ndarray       # (k, size*size) orthonormal: the templates' principal components
    coef: np.ndarray        # (T, k): vectors ~ coef @ basis
    highpass: bool = True   # templates (and the image) emboss-filtered


def template_bank(n_angles: int = 16, spans: tuple[float, ...] = (0.72, 1.0),
                  notches: tuple[float, ...] = (0.04, 0.1), size: int = TEMPLATE_PX, energy: float = 0.97,
                  highpass: bool = True) -> Bank:
    """Templates over ``n_angles`` full-turn angles, fin spans (fractions of ``size``) and notch
    angles; each emboss-filtered, zero-mean and unit-norm. The bank is scored through its principal
    components holding ``energy`` of it (steerable in effect: a rotated template is a mix of a few
    fixed filters), which is ~4x fewer products than the templates themselves."""
    vecs, angles, sp = [], [], []
    for k in range(n_angles):
        ang = 2 * np.pi * k / n_angles
        for f in spans:
            for notch in notches:
                length = f * size / WINDOW_OF_FL
                m = fork_mask(size + 2, ang, length, notch)
                t = (emboss(m) if highpass else m)[1:-1, 1:-1].ravel()
                t = t - t.mean()
                vecs.append(t / np.linalg.norm(t))
                angles.append(ang)
                sp.append(SPAN_OF_FL * length)
    vecs = np.array(vecs, np.float32)
    _, sv, vt = np.linalg.svd(vecs, full_matrices=False)
    k = int(np.searchsorted(np.cumsum(sv ** 2) / np.sum(sv ** 2), energy)) + 1
    basis = vt[:k].astype(np.float32)
    return Bank(vecs, np.array(angles), np.array(sp), size, basis, (vecs @ basis.T).astype(np.float32), highpass)


_BANK: Bank | None = None


def default_bank() -> Bank:
    global _BANK
    if _BANK is None:
        _BANK = template_bank()
    return _BANK


def concat(parts: list[Fins]) -> Fins:
    if not parts:
        return Fins.empty()
    body = None
    if any(o.body is not None for o in parts):
        body = np.concatenate([np.full(len(o), np.nan) if o.body is None else o.body for o in parts])
    return Fins(*(np.concatenate([getattr(o, k) for o in parts]) for k in ("xy", "angle", "span_px", "score",
                                                                           "polarity")), body)


def suppress(fins: Fins, max_fins: int, reach_of_span: float = 0.5) -> np.ndarray:
    """Non-maximum suppression across levels: indices of the candidates kept, best first; one
    within ``reach_of_span`` of the larger span of a better one goes; at most ``max_fins`` remain."""
    order = np.argsort(-fins.score, kind="stable")
    fins = fins.take(order)
    d = np.linalg.norm(fins.xy[:, None] - fins.xy[None], axis=2)
    reach = reach_of_span * np.maximum(fins.span_px[:, None], fins.span_px[None])
    close = np.triu(d < reach, k=1)
    keep = np.ones(len(fins), bool)
    for i in range(len(fins)):                     # a few dozen candidates
        if keep[i]:
            keep[np.flatnonzero(close[i])] = False
    return order[np.flatnonzero(keep)[:max_fins]]


_REMAP_ROWS = 32767


def down_side(angle: np.ndarray) -> np.ndarray:
    """(N,) +1 or -1 per frame of axis ``angle``: the sign that turns the frame's normal (the axis
    turned +90 degrees, ``sample_frames``) to point down the image. A frame sampled with its ``ys``
    times this sees a fish's back on the same side whichever way it swims, so a fish and its mirror
    image give the same samples: with the plain normal, a fish swimming towards -u is seen upside
    down, and what is scored or learned on the frame (eq. 13's window, the learned locators) answers
    differently for the two directions (issue 7: a fork net placing 0.90 of one direction's forks
    and 0.53 of the other's on an outside renderer's fish)."""
    return np.where(np.cos(np.asarray(angle, float)) >= 0, 1.0, -1.0)


def sample_frames(img: np.ndarray, centres: np.ndarray, axes: np.ndarray, xs: np.ndarray,
                  ys: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, ny, nx) of img in each candidate's own frame: the point centre + x axis
    + y normal, with normal = axis turned +90 degrees (image coordinates). ``xs``/``ys``: (nx,) and
    (ny,) offsets shared by all, or (N, nx) / (N, ny) per candidate. Outside the image: NaN. A
    colour image gives (N, ny, nx, C)."""
    out, off = sample_frames_raw(img, centres, axes, xs, ys)
    out = out.astype(np.float32, copy=False)
    if off is not None:
        out[off] = np.nan
    return out


def sample_frames_raw(img: np.ndarray, centres: np.ndarray, axes: np.ndarray, xs: np.ndarray,
                      ys: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """``sample_frames`` before the samples outside the image are set to NaN: the samples in the
    image's own dtype for uint8 (what cv2.remap gives: no float copy) and a mask (N, ny, nx) of those
    outside (None when there are none); float images give float32 with NaN already and None."""
    centres = np.asarray(centres, float).reshape(-1, 2)
    axes = np.asarray(axes, float).reshape(-1, 2)
    N = len(centres)
    # shared offsets stay (1, n): they broadcast in the sums below (np.broadcast_to's call costs more)
    xs, ys = np.asarray(xs, float), np.asarray(ys, float)
    xs, ys = xs.reshape(-1, xs.shape[-1]), ys.reshape(-1, ys.shape[-1])
    ny, nx = ys.shape[1], xs.shape[1]
    img = np.asarray(img)
    if N == 0:
        return np.zeros((0, ny, nx) + img.shape[2:], np.uint8 if img.dtype == np.uint8 else np.float32), None
    if N * ny >= _REMAP_ROWS:
        # cv2.remap takes maps of fewer than 32767 rows: many candidates go in batches
        step = max(1, (_REMAP_ROWS - 1) // ny)
        xs, ys = np.broadcast_to(xs, (N, nx)), np.broadcast_to(ys, (N, ny))
        parts = [sample_frames_raw(img, centres[k:k + step], axes[k:k + step], xs[k:k + step], ys[k:k + step])
                 for k in range(0, N, step)]
        offs = None
        if any(o is not None for _, o in parts):
            offs = np.concatenate([np.zeros(p.shape[:3], bool) if o is None else o for p, o in parts])
        return np.concatenate([p for p, _ in parts]), offs
    maps, lo, hi = [], [], []
    for k, normal in ((0, -axes[:, 1, None]), (1, axes[:, 0, None])):   # normal: the axis turned +90
        along = centres[:, k, None] + xs * axes[:, k, None]              # (N, nx), float64
        across = ys * normal                                             # (N, ny)
        m = np.empty((N, ny, nx), np.float32)    # summed in float64, rounded once, no float64 copy
        np.add(along[:, None, :], across[:, :, None], out=m, casting="same_kind")
        maps.append(m.reshape(N * ny, nx))
        # addition and rounding are monotonic: a frame's extreme samples are these, exactly
        lo.append(along.min(axis=1) + across.min(axis=1))
        hi.append(along.max(axis=1) + across.max(axis=1))
    if img.dtype != np.uint8:
        img = img.astype(np.float32, copy=False)
        out = cv2.remap(img, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=(np.nan,) * 4)
        return out.reshape((N, ny, nx) + img.shape[2:]), None
    # remap of uint8 is ~3x faster; values keep 1/2 grey level
    out = cv2.remap(img, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = out.reshape((N, ny, nx) + img.shape[2:])
    h, w = img.shape[:2]
    # only frames reaching past the image's edge need the per-sample test, and not those
    # wholly outside it (1 px to spare either way)
    gone = (hi[0] < -1) | (lo[0] > w) | (hi[1] < -1) | (lo[1] > h)
    edge = np.flatnonzero(~gone & ((lo[0] < 1) | (hi[0] > w - 2) | (lo[1] < 1) | (hi[1] > h - 2)))
    if not gone.any() and len(edge) == 0:
        return out, None
    off = np.zeros((N, ny, nx), bool)
    off[gone] = True
    if len(edge):
        mx, my = maps[0].reshape(N, ny, nx)[edge], maps[1].reshape(N, ny, nx)[edge]
        off[edge] = (mx < 0) | (mx > w - 1) | (my < 0) | (my > h - 1)
    return out, off


def fin_scores(pyr: list[np.ndarray], fins: Fins, bank: Bank | None = None, upright: bool = False) -> np.ndarray:
    """Eq. (13) where a fork has been located: the best |NCC| (N,) of the bank's templates with the
    fin's own angle, on the emboss-filtered neighbourhood sampled in the fin's frame at the
    templates' scale (the fin's span sets it). 1 = a textbook forked tail."""
    bank = bank or default_bank()
    N = len(fins)
    if N == 0:
        return np.zeros(0)
    n = bank.size + 2
    at_zero = np.abs(np.angle(np.exp(1j * bank.angle))) < 1e-6            # templates at angle 0
    vecs, spans = bank.vectors[at_zero], bank.span[at_zero]
    # one window per fin at the larger template's scale: its span fills the same share of it
    px = fins.span_px / spans.max()                                         # image px per template px
    t = (np.arange(n) - (n - 1) / 2)[None] * px[:, None]
    lev = np.clip(np.floor(np.log2(np.maximum(px, 1.0))).astype(int), 0, len(pyr) - 1)
    win = np.full((N, n, n), np.nan, np.float32)
    axes = np.column_stack((np.cos(fins.angle), np.sin(fins.angle)))
    # upright: the window's v down the image, a fish seen the same whichever way it swims
    across = t * down_side(fins.angle)[:, None] if upright else t
    for k in np.unique(lev):
        idx = np.flatnonzero(lev == k)
        f = 2.0 ** -k
        w = sample_frames(pyr[k], (fins.xy[idx] + 0.5) * f - 0.5, axes[idx], t[idx] * f, across[idx] * f)
        win[idx] = w.mean(axis=3) if w.ndim == 4 else w
    win = np.nan_to_num(win, nan=float(np.nanmean(win)) if np.isfinite(win).any() else 0.0)
    e = np.stack([emboss(w)[1:-1, 1:-1].ravel() for w in win]) if bank.highpass else win[:, 1:-1, 1:-1].reshape(N, -1)
    e = e - e.mean(axis=1, keepdims=True)
    ncc = (e @ vecs.T) / np.maximum(np.linalg.norm(e, axis=1), 1e-6)[:, None]
    return np.abs(ncc).max(axis=1)


def bank_proposals(img: np.ndarray, sx: float, sy: float, k: int, n_levels: int = 2, stride: int = 2,
                   keep: float = 0.1, bank: Bank | None = None, signed: bool = True) -> Fins:
    """Eq. (13) over a whole reduced image: the ``k`` best fork candidates (full-resolution pixels;
    ``sx``, ``sy``: full-resolution px per ``img`` px), a second proposer beside the bodies' ends.

    ``img``: float32 (h, w); ``signed``: fish brighter than the water (``water_distance``), so only
    positive responses count, else either sign does. It is scored at ``n_levels`` halvings (the bank's two sizes
    cover fish ~1.4x apart; each halving doubles them), at grid points every ``stride`` px whose
    local emboss energy is in the top ``keep`` share; the peaks, non-maximum suppressed across
    levels (half the larger span), best first."""
    bank = bank or default_bank()
    h = bank.size // 2
    out = []
    level = np.asarray(img, np.float32)
    for lv in range(n_levels):
        if min(level.shape) < 2 * bank.size:
            break
        f = emboss(level) if bank.highpass else level
        energy = cv2.boxFilter(f * f, -1, (bank.size, bank.size), normalize=True)
        grid = energy[h:-h:stride, h:-h:stride]
        thr = order_stats.quantile(grid, 1.0 - keep)
        gy, gx = np.nonzero(grid >= max(thr, 1e-6))
        ys, xs = gy * stride + h, gx * stride + h
        if len(ys) == 0:                          # flat water: nothing to score
            level = half(level)
            continue
        win = np.lib.stride_tricks.sliding_window_view(f, (bank.size, bank.size))[ys - h, xs - h].reshape(len(ys), -1)
        mean = cv2.boxFilter(f, -1, (bank.size, bank.size), normalize=True)[ys, xs]
        norm = np.sqrt(np.maximum(energy[ys, xs] - mean * mean, 0) * bank.size ** 2)
        ncc = ((win @ bank.basis.T) @ bank.coef.T) / np.maximum(norm, 1e-6)[:, None]
        ncc = ncc if signed else np.abs(ncc)
        best = ncc.argmax(axis=1)
        sc = ncc[np.arange(len(ys)), best]
        # local maxima on the grid (one template's reach)
        g = np.full(grid.shape, -1.0, np.float32)
        g[gy, gx] = sc
        r = max(1, bank.size // (2 * stride))
        mx = cv2.dilate(g, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
        pk = np.flatnonzero((sc > 0) & (sc >= mx[gy, gx]))
        pk = pk[np.argsort(-sc[pk], kind="stable")[: 2 * k]]
        f2 = 2.0 ** lv
        xy = np.column_stack((((xs[pk] + 0.5) * f2 - 0.5 + 0.5) * sx - 0.5,
                              ((ys[pk] + 0.5) * f2 - 0.5 + 0.5) * sy - 0.5))
        out.append(Fins(xy, bank.angle[best[pk]], bank.span[best[pk]] * f2 * sx, sc[pk], np.ones(len(pk))))
        level = half(level)
    if not out:
        return Fins.empty()
    allf = concat(out)
    return allf.take(suppress(allf, k, 0.5))
