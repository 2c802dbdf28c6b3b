"""Caudal-fin detection (paper section 4.2.1): emboss high-pass filter, a bank of fork templates over
angles and scales (eq. 13), local maxima above a threshold; then the fork's innermost point
located at full resolution (``vision.fork``).

Eq. (13) is f_o(x, y) = max_i sum template_i . f*(x + xt, y + yt) over the emboss-filtered,
illumination-compensated image f*. Here each template is a forked tail drawn at one angle and size
(``fork_mask``) and passed through the same emboss kernel, so it matches the transitions a fork
leaves in the filtered image (a matched filter). The sum is normalised (zero-mean NCC): a fin in
dim water scores as high as one in sunlit water, and a threshold means the same everywhere. Its
sign is the fin's polarity (darker or brighter than the water), so the bank serves both.

Speed. Fins are looked for on a pyramid of reduced images (``levels``): level 0 is the image
scaled so that the smallest fish the survey reports (``min_fish_frac`` of the image width) has a
fin span of about a template's size, each next level halves it, so the same 15 px templates cover
fish 8x larger; everything scales with the image, not with 1280x960. The bank is not run over the
whole image: edges are where a fork can be, so only grid points (every ``stride`` px) whose
local emboss energy is in the image's top part are scored, all templates at once as one matrix
product of their windows. Peaks of the score over the grid are the candidates.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

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

    def __len__(self) -> int:
        return len(self.xy)

    def take(self, idx) -> Fins:
        return Fins(self.xy[idx], self.angle[idx], self.span_px[idx], self.score[idx], self.polarity[idx])

    @staticmethod
    def empty() -> Fins:
        z = np.zeros(0)
        return Fins(np.zeros((0, 2)), z, z.copy(), z.copy(), z.copy())


def fork_mask(size: int, angle: float, span: float, notch_deg: float = 60.0, oversample: int = 8) -> np.ndarray:
    """Anti-aliased mask (size, size) float32 of a forked tail: 1 fish, 0 water. Its innermost fork
    point at the window centre, the body towards ``angle`` (rad, image u right v down), the lobes'
    tips ``span`` px apart and their inner edges ``notch_deg`` off the axis (90 = no fork)."""
    h = span / 2
    a = np.radians(notch_deg)
    lobe = h / np.sin(a)                                   # inner edge, vertex to tip
    tip = np.array([-lobe * np.cos(a), h])
    # fish frame: x towards the head, y across; one lobe, mirrored
    half = [(0.0, 0.0), tuple(tip), (tip[0] + 0.25 * h, h * 1.02), (0.45 * h, 0.42 * h), (2.0 * h, 0.45 * h)]
    pts = np.array(half + [(x, -y) for x, y in reversed(half)], dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    rot = pts @ np.array([[c, s], [-s, c]])
    centre = (size - 1) / 2
    big = np.zeros((size * oversample, size * oversample), np.uint8)
    poly = np.round(((rot + centre + 0.5) * oversample - 0.5) * 16).astype(np.int32)
    cv2.fillPoly(big, [poly], 255, lineType=cv2.LINE_AA, shift=4)
    return cv2.resize(big, (size, size), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0


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


def template_bank(n_angles: int = 16, spans: tuple[float, ...] = (0.72, 1.0),
                  notches: tuple[float, ...] = (50.0, 65.0), size: int = TEMPLATE_PX, energy: float = 0.97) -> Bank:
    """Templates over ``n_angles`` full-turn angles, fin spans (fractions of ``size``) and notch
    angles; each emboss-filtered, zero-mean and unit-norm. The bank is scored through its principal
    components holding ``energy`` of it (steerable in effect: a rotated template is a mix of a few
    fixed filters), which is ~4x fewer products than the templates themselves."""
    vecs, angles, sp = [], [], []
    for k in range(n_angles):
        ang = 2 * np.pi * k / n_angles
        for f in spans:
            for notch in notches:
                t = emboss(fork_mask(size + 2, ang, f * size, notch))[1:-1, 1:-1].ravel()
                t = t - t.mean()
                vecs.append(t / np.linalg.norm(t))
                angles.append(ang)
                sp.append(f * size)
    vecs = np.array(vecs, np.float32)
    _, sv, vt = np.linalg.svd(vecs, full_matrices=False)
    k = int(np.searchsorted(np.cumsum(sv ** 2) / np.sum(sv ** 2), energy)) + 1
    basis = vt[:k].astype(np.float32)
    return Bank(vecs, np.array(angles), np.array(sp), size, basis, (vecs @ basis.T).astype(np.float32))


_BANK: Bank | None = None


def default_bank() -> Bank:
    global _BANK
    if _BANK is None:
        _BANK = template_bank()
    return _BANK


def _grid_scores(f: np.ndarray, bank: Bank, stride: int, keep: float, min_energy: float):
    """NCC of every template at grid points of the embossed level image f whose local energy is in
    the top ``keep`` fraction. Returns (ys, xs, best |ncc|, signed ncc, template index)."""
    h = bank.size // 2
    energy = cv2.boxFilter(f * f, -1, (bank.size, bank.size), normalize=True)
    grid = energy[h:-h:stride, h:-h:stride] if energy.shape[0] > 2 * h and energy.shape[1] > 2 * h else None
    if grid is None or grid.size == 0:
        return (np.zeros(0, int),) * 2 + (np.zeros(0),) * 2 + (np.zeros(0, int),)
    flat = grid.ravel()
    sample = flat[:: max(1, flat.size // 4096)]
    thr = max(float(np.partition(sample, int((1.0 - keep) * (sample.size - 1)))[int((1.0 - keep) * (sample.size - 1))]),
              min_energy)
    gy, gx = np.nonzero(grid >= thr)
    ys, xs = gy * stride + h, gx * stride + h
    win = np.lib.stride_tricks.sliding_window_view(f, (bank.size, bank.size))[ys - h, xs - h]
    win = win.reshape(len(ys), -1)
    mean = cv2.boxFilter(f, -1, (bank.size, bank.size), normalize=True)[ys, xs]
    n = bank.size * bank.size
    norm = np.sqrt(np.maximum(energy[ys, xs] - mean * mean, 0) * n)
    # templates are zero-mean, so the window's mean drops out of the products
    ncc = ((win @ bank.basis.T) @ bank.coef.T) / np.maximum(norm, 1e-6)[:, None]
    best = np.abs(ncc).argmax(axis=1)
    signed = ncc[np.arange(len(ys)), best]
    return ys, xs, np.abs(signed), signed, best


def _peaks(shape, stride, ys, xs, score, radius_cells: int, thr: float) -> np.ndarray:
    """Indices of grid points that are local maxima of ``score`` within ``radius_cells`` and >= thr."""
    g = np.zeros(((shape[0] + stride - 1) // stride + 1, (shape[1] + stride - 1) // stride + 1), np.float32)
    gy, gx = ys // stride, xs // stride
    g[gy, gx] = score
    k = 2 * radius_cells + 1
    mx = cv2.dilate(g, np.ones((k, k), np.uint8))
    return np.flatnonzero((score >= thr) & (score >= mx[gy, gx]))


def level_scales(width: int, min_fish_frac: float, n_levels: int, size: int = TEMPLATE_PX) -> list[float]:
    """Scale factors of the pyramid levels: at level 0 a fish ``min_fish_frac`` of the image width
    long has a fin span of ~0.8 template."""
    fin_span_px = SPAN_OF_FL * min_fish_frac * width
    s0 = min(1.0, 0.8 * size / fin_span_px)
    return [s0 / 2 ** k for k in range(n_levels)]


def working_levels(pyr: list[np.ndarray], prep, min_fish_frac: float = 0.08, n_levels: int = 3,
                   size: int = TEMPLATE_PX) -> list[tuple[float, float, np.ndarray]]:
    """The images the bank runs on: (x scale, y scale, pre-processed level image) per level, each
    resized from the Gaussian pyramid ``pyr`` of the grey image (its level just above, so the
    resize needs no anti-aliasing of its own). ``prep(img) -> float32`` is applied to each (noise
    reduction and row compensation)."""
    H, W = pyr[0].shape[:2]
    out = []
    for s in level_scales(W, min_fish_frac, n_levels, size):
        dims = (max(int(round(W * s)), 1), max(int(round(H * s)), 1))
        if min(dims) < 2 * size:
            break
        k = min(int(np.floor(np.log2(1.0 / s))), len(pyr) - 1)
        src = pyr[k]
        small = src if src.shape[1] == dims[0] else cv2.resize(src, dims, interpolation=cv2.INTER_LINEAR)
        out.append((W / dims[0], H / dims[1], prep(small)))
    return out


def detect_fins(levels: list[tuple[float, float, np.ndarray]], *, threshold: float = 0.5, keep: float = 0.2,
                stride: int = 2, max_fins: int = 40, bank: Bank | None = None) -> Fins:
    """Fork candidates (coarse: level-pixel accuracy) on the working levels (``working_levels``).

    ``threshold``: least |NCC|. ``keep``: fraction of grid points, by local emboss energy, whose
    templates are scored."""
    bank = bank or default_bank()
    out = []
    for sx, sy, img in levels:
        f = emboss(img)
        noise = float(np.median(np.abs(f))) + 1e-3
        ys, xs, sc, signed, best = _grid_scores(f, bank, stride, keep, min_energy=(2.0 * noise) ** 2)
        pk = _peaks(f.shape, stride, ys, xs, sc, max(1, bank.size // (2 * stride)), threshold)
        pk = pk[np.argsort(-sc[pk], kind="stable")[: 2 * max_fins]]
        xy = np.c_[(xs[pk] + 0.5) * sx - 0.5, (ys[pk] + 0.5) * sy - 0.5]
        out.append(Fins(xy, bank.angle[best[pk]], bank.span[best[pk]] * sx, sc[pk], np.sign(signed[pk])))
    if not out:
        return Fins.empty()
    fins = Fins(*(np.concatenate([getattr(o, k) for o in out]) for k in ("xy", "angle", "span_px", "score",
                                                                          "polarity")))
    return suppress(fins, max_fins)


def suppress(fins: Fins, max_fins: int) -> Fins:
    """Non-maximum suppression across levels: a candidate within half the span of a better one
    goes; at most ``max_fins`` remain, best first."""
    order = np.argsort(-fins.score, kind="stable")
    fins = fins.take(order)
    d = np.linalg.norm(fins.xy[:, None] - fins.xy[None], axis=2)
    reach = 0.5 * np.maximum(fins.span_px[:, None], fins.span_px[None])
    close = np.triu(d < reach, k=1)
    keep = np.ones(len(fins), bool)
    for i in range(len(fins)):                     # a few dozen candidates
        if keep[i]:
            keep[np.flatnonzero(close[i])] = False
    return fins.take(np.flatnonzero(keep)[:max_fins])


def sample_frames(img: np.ndarray, centres: np.ndarray, axes: np.ndarray, xs: np.ndarray,
                  ys: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, ny, nx) of img in each candidate's own frame: the point centre + x axis
    + y normal, with normal = axis turned +90 degrees (image coordinates). ``xs``/``ys``: (nx,) and
    (ny,) offsets shared by all, or (N, nx) / (N, ny) per candidate. Outside the image: NaN."""
    centres = np.asarray(centres, float).reshape(-1, 2)
    axes = np.asarray(axes, float).reshape(-1, 2)
    N = len(centres)
    xs = np.broadcast_to(np.asarray(xs, float), (N, np.shape(xs)[-1]))
    ys = np.broadcast_to(np.asarray(ys, float), (N, np.shape(ys)[-1]))
    ny, nx = ys.shape[1], xs.shape[1]
    if N == 0:
        return np.zeros((0, ny, nx), np.float32)
    normal = np.c_[-axes[:, 1], axes[:, 0]]
    maps = []
    for k in range(2):
        m = (centres[:, k, None, None] + xs[:, None, :] * axes[:, k, None, None]
             + ys[:, :, None] * normal[:, k, None, None])
        maps.append(m.reshape(N * ny, nx).astype(np.float32))
    out = cv2.remap(np.asarray(img, np.float32), maps[0], maps[1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return out.reshape(N, ny, nx)
