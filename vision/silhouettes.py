"""Fish silhouettes against a local water/background model, and fork proposals from their outlines.

The row compensation of eq. (12) flattens sunlit water but also turns a near fish into a band across
the frame (its rows' statistics are the fish's), and a reef behind the fish is no flat water at
all. So fish are segmented here against a background estimated per neighbourhood, in CIE Lab (the
colour distance a person sees, lightness and hue alike): a first background is a median over a
large window of a reduced copy; pixels far from it are masked out and the background is estimated
again from what remains (normalised convolution), so a big fish does not bleed into its own
background. Each pixel's distance to it is divided by the local spread of the background's own
distances (clutter raises its own threshold: reef texture is not a fish, open water's noise is
small), and thresholded at a few levels (a low level finds faint fish, a high one splits fish that
touch at the low one).

On each silhouette's outline, the caudal fork is a concavity between two lobes: a convexity
defect (``cv2.convexityDefects``) near one end of the body's main axis, deep against the body's
length, whose hull edge spans the axis. Each such defect's deepest point is a fork proposal,
pointing along the axis to the far end (where the snout is); both axis ends are proposals too
(a fin too faint for the mask leaves the body ending at the caudal peduncle). Each proposal is
located by ``vision.fork``; snout candidates are the far end of the silhouette a located fork
belongs to (``silhouette_tips``).

Measured and left out (bench/bench_survey_underwater.py, 107 scenes, 203 fully visible fish): the
notch re-measured on the outline of a full-resolution crop thresholded against this background
(the deepest convexity defect, sub-pixel): from near-true starts it placed 15 of 76 rendered forks
within 2 % (the crossings of ``vision.fork``: 27), and in the survey it added no fish found, only
false ones (precision 1.0 without it, 0.95 with it): a half-transparent fin over reef or another
fish has no outline of its own at any one threshold.
"""
from __future__ import annotations

import cv2
import numpy as np

from vision import order_stats
from vision.fins import SPAN_OF_FL, Fins
from vision.labels import regions


def _lab(img: np.ndarray) -> np.ndarray:
    """float32 (h, w, C): CIE Lab of a BGR image (OpenCV's 8-bit scaling), a grey image as is."""
    if img.ndim == 2:
        return img.astype(np.float32)[..., None]
    return cv2.cvtColor(np.ascontiguousarray(img[..., :3]), cv2.COLOR_BGR2LAB).astype(np.float32)


def _colour_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance (h, w) float32 between two (h, w, C) images (OpenCV: ~8x numpy's norm)."""
    d = np.ascontiguousarray(a - b, dtype=np.float32)
    sq = cv2.transform(d * d, np.ones((1, d.shape[2]), np.float32))
    return cv2.sqrt(sq).reshape(a.shape[:2])


def _smooth_masked(values: np.ndarray, weight: np.ndarray, sigma_frac: float) -> np.ndarray:
    """Normalised convolution: a Gaussian average of ``values`` (h, w, C) where ``weight`` (h, w) is
    1, on a 1/4 copy (cheap at any sigma), back at full size. Where nothing is weighted nearby, the
    plain average."""
    h, w = weight.shape
    sh, sw = max(4, h // 4), max(4, w // 4)
    v = cv2.resize(values * weight[..., None], (sw, sh), interpolation=cv2.INTER_AREA).reshape(sh, sw, -1)
    m = cv2.resize(weight, (sw, sh), interpolation=cv2.INTER_AREA)
    plain = cv2.resize(values, (sw, sh), interpolation=cv2.INTER_AREA).reshape(sh, sw, -1)
    s = max(1.0, sigma_frac * sw)
    vb = cv2.GaussianBlur(v, (0, 0), s, borderType=cv2.BORDER_REFLECT).reshape(sh, sw, -1)
    mb = cv2.GaussianBlur(m, (0, 0), s, borderType=cv2.BORDER_REFLECT)
    pb = cv2.GaussianBlur(plain, (0, 0), s, borderType=cv2.BORDER_REFLECT).reshape(sh, sw, -1)
    out = np.where(mb[..., None] > 0.05, vb / np.maximum(mb, 1e-6)[..., None], pb)
    return cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR).reshape(h, w, -1)


def background_distance(img: np.ndarray, k_first: float = 3.0, sigma_frac: float = 0.08,
                        min_spread: float = 1.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How unlike its local background each pixel is, in units of the background's local spread
    (float32 (h, w), >= 0), with the background (h, w, C) (Lab, or grey) and the spread (h, w) it
    was measured against. ``img``: BGR or grey uint8, a reduced working copy."""
    lab = cv2.GaussianBlur(_lab(img), (0, 0), 1.0).reshape(img.shape[0], img.shape[1], -1)
    h, w = lab.shape[:2]
    # first background: a median over ~0.4 of the width of a ~40 px wide copy
    sw = 40
    sh = max(4, int(round(sw * h / w)))
    small = cv2.resize(np.clip(lab, 0, 255).astype(np.uint8), (sw, sh), interpolation=cv2.INTER_AREA)
    bg = cv2.resize(cv2.medianBlur(small, 15), (w, h), interpolation=cv2.INTER_LINEAR).astype(np.float32)
    d = _colour_distance(lab, bg.reshape(lab.shape))
    flat = d[::2, ::2].ravel()
    med = order_stats.median(flat)
    mad = 1.4826 * order_stats.median(np.abs(flat - med))
    fg = (d > med + k_first * max(mad, 0.5)).astype(np.uint8)
    fg = cv2.dilate(fg, np.ones((5, 5), np.uint8))
    keep = (1 - fg).astype(np.float32)
    bg = _smooth_masked(lab, keep, sigma_frac)
    d = _colour_distance(lab, bg)
    spread = np.sqrt(_smooth_masked((d * d)[..., None], keep, 2 * sigma_frac)[..., 0])
    floor = max(min_spread, order_stats.median(spread) * 0.5)
    spread = np.maximum(spread, floor).astype(np.float32)
    return d / spread, bg.astype(np.float32), spread


def fish_masks(z: np.ndarray, ks: tuple[float, ...] = (2.0, 4.0), seed_k: float = 5.0) -> list[np.ndarray]:
    """uint8 masks (one per level k) of pixels more than k local spreads from the background, kept
    where connected to a pixel more than ``seed_k`` spreads from it (hysteresis: a faint fin joins
    its body, faint clutter alone does not)."""
    seed = z > max(seed_k, max(ks))
    out = []
    for k in ks:
        m = cv2.morphologyEx((z > k).astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        n, lab = cv2.connectedComponents(m, connectivity=8)
        good = np.zeros(n, np.uint8)
        good[np.unique(lab[seed & (m > 0)])] = 1
        good[0] = 0
        out.append(good[lab])
    return out


def outline_forks(mask: np.ndarray, sx: float, sy: float, min_len_px: float, min_elong: float = 1.8,
                  max_bodies: int = 30, min_depth: float = 0.035, end_reach: float = 0.35) -> tuple[Fins, np.ndarray]:
    """Fork proposals on every elongated silhouette of ``mask`` at least ``min_len_px`` long
    (working px): the deep convexity defects near an end of the main axis and both axis ends.
    Returns the proposals in full-resolution px (``sx``, ``sy``: full / working px), angle towards
    the far end, span ``SPAN_OF_FL`` of the silhouette's length, ``body`` the axis; and per
    proposal the silhouette's length (full-resolution px)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    sizes = [max(cv2.boundingRect(c)[2:]) for c in contours]
    order = [i for i in np.argsort(-np.array(sizes, float)) if sizes[i] >= min_len_px][:max_bodies]
    xy, ang, length, score = [], [], [], []
    scale = np.array([sx, sy])
    for i in order:                                       # a few dozen silhouettes
        c = contours[i]
        pts = c[:, 0].astype(np.float64)
        m = cv2.moments(c)
        if m["m00"] <= 0:
            continue
        centre = np.array([m["m10"], m["m01"]]) / m["m00"]
        cov = np.array([[m["mu20"], m["mu11"]], [m["mu11"], m["mu02"]]]) / m["m00"]
        evals, evecs = np.linalg.eigh(cov)
        if evals[0] <= 0 or np.sqrt(evals[1] / evals[0]) < min_elong:
            continue
        axis = evecs[:, 1]
        t = (pts - centre) @ axis
        lo, hi = float(t.min()), float(t.max())
        L = hi - lo
        if L < min_len_px:
            continue
        cand = [(centre + lo * axis, 1.0, 0.5), (centre + hi * axis, -1.0, 0.5)]
        if len(c) >= 5:
            hull = cv2.convexHull(c, returnPoints=False)
            try:
                defects = cv2.convexityDefects(c, hull)
            except cv2.error:                              # a self-touching outline
                defects = None
            if defects is not None:
                normal = np.array([-axis[1], axis[0]])
                for s_i, e_i, f_i, depth in defects.reshape(-1, 4):
                    dep = depth / 256.0
                    if dep < max(min_depth * L, 1.5):
                        continue
                    f = pts[f_i]
                    tf = (f - centre) @ axis
                    # the lobe tips lie on either side of the axis line
                    if ((pts[s_i] - f) @ normal) * ((pts[e_i] - f) @ normal) >= 0:
                        continue
                    if tf - lo <= end_reach * L:
                        cand.append((f, 1.0, 1.0 + dep / L))
                    elif hi - tf <= end_reach * L:
                        cand.append((f, -1.0, 1.0 + dep / L))
        for p, toward, sc in cand:
            xy.append(((p[0] + 0.5) * sx - 0.5, (p[1] + 0.5) * sy - 0.5))
            d = toward * axis * scale
            ang.append(np.arctan2(d[1], d[0]))
            length.append(L * 0.5 * (sx + sy))
            score.append(sc)
    if not xy:
        return Fins.empty(), np.zeros(0)
    ang_a = np.array(ang)
    length_a = np.array(length)
    fins = Fins(np.array(xy), ang_a, SPAN_OF_FL * length_a, np.array(score), np.ones(len(xy)), ang_a.copy())
    return fins, length_a


def components(masks: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(labels, stats) of every mask's 8-connected components."""
    return [regions(m)[1:3] for m in masks]


def silhouette_tips(comps: list[tuple[np.ndarray, np.ndarray]], sx: float, sy: float, xy: np.ndarray,
                    angle: np.ndarray, span_px: np.ndarray, cone_deg: float = 25.0) -> np.ndarray:
    """Snout candidates (N, len(comps), 2), full-resolution px (NaN: none): for each fork (``xy``,
    ``angle`` towards the head, ``span_px``), the silhouette met just ahead of it, and that
    silhouette's farthest point from the fork within ``cone_deg`` of the axis (the snout is the
    body's farthest point from the fork; the cone keeps a fish touching it out)."""
    N = len(xy)
    out = np.full((N, len(comps), 2), np.nan)
    if N == 0:
        return out
    scale = np.array([sx, sy])
    p0 = (np.asarray(xy, float) + 0.5) / scale - 0.5
    d = np.column_stack((np.cos(angle), np.sin(angle))) / scale
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    reach = np.asarray(span_px, float) / (0.5 * (sx + sy))
    steps = np.array([0.3, 0.6, 1.0, 1.5])
    cos_min = np.cos(np.radians(cone_deg))
    for c, (lab, stats) in enumerate(comps):
        h, w = lab.shape
        probes = np.rint(p0[:, None] + (steps[None, :, None] * reach[:, None, None]) * d[:, None]).astype(int)
        inside = (probes[..., 0] >= 0) & (probes[..., 0] < w) & (probes[..., 1] >= 0) & (probes[..., 1] < h)
        hit = np.where(inside, lab[np.clip(probes[..., 1], 0, h - 1), np.clip(probes[..., 0], 0, w - 1)], 0)
        first = np.zeros(N, int)
        for n in range(N):                               # a few dozen forks
            nz = hit[n][hit[n] > 0]
            if len(nz) == 0:
                continue
            first[n] = nz[0]
            x0, y0, bw, bh = stats[first[n], :4]
            ys, xs = np.nonzero(lab[y0:y0 + bh, x0:x0 + bw] == first[n])
            rel = np.column_stack((xs + x0, ys + y0)) - p0[n]
            dist = np.linalg.norm(rel, axis=1)
            ahead = rel @ d[n] >= cos_min * dist
            if not ahead.any():
                continue
            far = dist[ahead].max()
            tip = (rel[ahead][dist[ahead] >= far - 1.0]).mean(axis=0) + p0[n]
            out[n, c] = (tip + 0.5) * scale - 0.5
    return out


def body_fill(comps: list[tuple[np.ndarray, np.ndarray]], sx: float, sy: float, a: np.ndarray, b: np.ndarray,
              samples: int = 32) -> np.ndarray:
    """Share (N,) of the segment from ``a`` to ``b`` (full-resolution px, (N, 2)) inside a silhouette of
    the first (lowest-threshold) mask: a fish's axis from fork to snout runs through its body; a
    fork paired with the snout of a fish ahead, or two points of reef, cross water."""
    N = len(a)
    if N == 0 or not comps:
        return np.ones(N)
    lab = comps[0][0]
    h, w = lab.shape
    u = np.linspace(0.0, 1.0, samples)[None, :, None]
    pts = a[:, None] + u * (b - a)[:, None]
    ok = np.all(np.isfinite(pts), axis=2)
    pts = np.where(ok[..., None], pts, 0.0)
    x = np.clip(np.rint((pts[..., 0] + 0.5) / sx - 0.5), 0, w - 1).astype(int)
    y = np.clip(np.rint((pts[..., 1] + 0.5) / sy - 0.5), 0, h - 1).astype(int)
    inside = lab[y, x] > 0
    return np.where(ok, inside, False).mean(axis=1)
