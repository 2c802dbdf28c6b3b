"""Fish regions seen from above, by region growing from seeds (the paper's section 4.2, Fig. 6).

On the working level's contrast map (vision.surface_prep): *seeds* are pixels clearly darker than
the floor (``seed_sigma`` noise levels and ``min_seed`` of the floor's brightness); a region grows
from them over connected pixels above a lower level (hysteresis: one connected-components pass,
regions without a seed dropped). Each region is then redrawn at full resolution in its own window:
its boundary is where the contrast falls to a fraction (``edge_level``) of the fish's own peak
contrast, so a pale fish and a dark one are cut at the same place of their edge blur, whatever the
lamps do to the floor; each sizeable piece the region falls into there is tried as a fish. Holes
(a lamp's reflection on a fish's back) are filled; a reflection *across* a fish's edge bites it,
which the shape checks and the score see.

Touching fish: a region whose silhouette is too wide for one fish is split by a watershed on its
distance transform (markers: its distinct thick cores).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vision.labels import regions
from vision.surface_prep import Contrast

# A region's contrast, cut at ``edge_level`` of its peak, may fall into pieces: a fish and the
# floor's stain it was grown into, a fish and a neighbour. Every piece overlapping the seed by at
# least this share of the largest overlap is tried as a fish (until 2026-12-07 the largest alone:
# a fish beside a larger stain was lost). Measured: bench 90 tanks recall 0.368 / 0.426 -> 0.371 /
# 0.432 at the same precision; drawn fish (bench/diag_surface_drawn.py, 60 tanks) right 344 -> 347
# (edge-on fins) and 281 -> 286 (forked), precision unchanged
COMPONENT_SHARE = 0.15
# touching fish: what the watershed's parts must be to be taken as fish each (``_fish_each``)
MIN_PART_LENGTH = 0.5     # each at least this share of the longest part's length (4 sd on its axis)
MAX_SOLIDITY_GAP = 0.2    # area / convex hull area: the parts' at most this far apart
MIN_PARTS_COVER = 0.7     # the parts together at least this share of the region


@dataclass(frozen=True)
class RegionParams:
    seed_sigma: float = 8.0        # seeds: contrast above this many noise levels ...
    min_seed: float = 0.12         # ... and above this fraction of the floor
    max_seed: float = 0.25         # ... but never more than this
    grow_sigma: float = 4.0        # growing: above this many noise levels ...
    min_grow: float = 0.05         # ... and this fraction
    edge_level: float = 0.4        # full-res boundary: this fraction of the region's peak contrast
    fin_level: float = 0.2         # pale fins joined down to this fraction
    min_length_frac: float = 0.025  # fish length in px >= this x image diagonal
    max_length_frac: float = 0.6
    min_elongation: float = 2.2    # split pieces: (4 sd along the axis)^2 / area, a loose bound
    min_slender: float = 5.0       # a fish: length^2 / area (fish from above ~6-11; an ellipse of
                                   # axes a > b: 4a / (pi b), so a blob 4x longer than wide fails)
    min_box_slender: float = 4.0   # coarse pre-check: bounding-box diagonal^2 / area (a fish ~8, a disc 2.5)
    min_coarse_slender: float = 3.0   # the same from the coarse mask's moments (fish ~6, a 2.4:1 ellipse 3)
    end_to_end_slender: float = 9.0   # only regions this slender are tried for a waist
    min_coarse_solidity: float = 0.6  # light regions: coarse area / convex hull area
    max_regions: int = 40          # per polarity, the largest: a textured floor seeds hundreds of blobs
    glare_level: int = 245         # a light region this bright (median) is a reflection, not a fish
    border_px: int = 2             # a region this close to the frame edge is cut by it


@dataclass
class Region:
    """One candidate fish at full resolution: its outer contour and mask in a window."""

    contour: np.ndarray       # (N, 2) float64 full-res pixels (u, v), closed, outer
    mask: np.ndarray          # (h, w) uint8 0/1, its window
    origin: np.ndarray        # (2,) window's top-left (u, v)
    peak: float               # its peak contrast
    glare: float              # fraction of its boundary next to glare (saturated, or brighter than the floor)
    outline: np.ndarray       # (M, 2) full-res outline with the pale fins (caudal fin) joined
    polarity: float           # +1 darker than the floor, -1 lighter
    whole: np.ndarray         # (h, w) uint8 0/1, the outline's filled mask, same window
    con: np.ndarray           # (h, w) float32 contrast (of its polarity) in the window


def _grow(c: Contrast, p: RegionParams, sign: float):
    """Hysteresis regions of one polarity: labels and stats of the kept ones, and their scale (full
    pixels per label pixel). Thresholds are taken at the working level; the masks are then pooled
    2x2 (a pixel is set if any of its four is) so the connected components run on a quarter of the
    pixels: regions are redrawn at full resolution anyway."""
    # a textured floor inflates the spread the noise is read from: never ask seeds for more than
    # ``max_seed`` of the floor's brightness (fish from above are darker or lighter than that)
    seed_t = min(max(p.seed_sigma * c.noise, p.min_seed), p.max_seed)
    grow_t = min(max(p.grow_sigma * c.noise, p.min_grow), p.max_seed / 2)
    work = c.work if sign > 0 else -c.work
    size = (work.shape[1] // 2, work.shape[0] // 2)
    def pool(mask):                 # 0/255 averaged over 2x2: non-zero where any of the four is set
        return (cv2.resize(mask.view(np.uint8) * np.uint8(255), size, interpolation=cv2.INTER_AREA) > 0).view(np.uint8)
    weak, strong = pool(work > grow_t), pool(work > seed_t)
    n, labels, stats, _ = regions(weak)
    seeded = np.bincount(labels[strong > 0], minlength=n) > 0
    seeded[0] = False
    w, h, area = (stats[:, k].astype(float) for k in (cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT, cv2.CC_STAT_AREA))
    scale = 2 * c.scale
    diag = float(np.hypot(*c.full.shape))
    seeded &= np.maximum(w, h) * scale >= 0.5 * p.min_length_frac * diag
    seeded &= w * w + h * h >= p.min_box_slender * area    # a blob (floor texture, glitter): not a fish
    keep = np.flatnonzero(seeded)
    keep = keep[np.argsort(-area[keep], kind="stable")[:p.max_regions]]
    return labels, stats, keep, 2 * c.scale


def _fill(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The largest outer contour of a 0/1 mask, and the mask with it filled (holes closed)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return mask, None
    best = max(contours, key=cv2.contourArea)
    out = np.zeros_like(mask)
    cv2.drawContours(out, [best], -1, 1, thickness=cv2.FILLED)
    return out, best.reshape(-1, 2)


def _elongation(mask: np.ndarray) -> float:
    """Length / mean width of a region (length from the spread of its pixels along its axis)."""
    area = float(mask.sum())
    ys, xs = np.nonzero(mask)
    if area < 10:
        return 0.0
    lam = np.linalg.eigvalsh(np.cov(np.vstack([xs, ys]).astype(np.float64)))
    length = 4.0 * np.sqrt(max(lam[1], 1e-9))          # a uniform bar of length L has sd L / 3.46
    return length * length / area


def _moment_length(mask: np.ndarray) -> tuple[float, float]:
    """(area, 4 sd along the principal axis) from the mask's moments (cheap: no pixel lists)."""
    m = cv2.moments(mask, binaryImage=True)
    if m["m00"] < 1:
        return 0.0, 0.0
    a, b, c = m["mu20"] / m["m00"], m["mu02"] / m["m00"], m["mu11"] / m["m00"]
    return m["m00"], 4.0 * float(np.sqrt(0.5 * (a + b) + np.sqrt(0.25 * (a - b) ** 2 + c * c)))


def _moment_slender(mask: np.ndarray) -> float:
    """(4 sd along the principal axis)^2 / area."""
    area, length = _moment_length(mask)
    return length * length / area if area >= 10 else 0.0


def _solidity(mask: np.ndarray) -> float:
    """Area / convex hull area of a small mask's largest outline (a fish's body ~0.8-0.9, a ragged
    patch of glitter or floor texture much less)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return 0.0
    c = max(contours, key=cv2.contourArea)
    hull = cv2.contourArea(cv2.convexHull(c))
    return float(cv2.contourArea(c) / hull) if hull > 0 else 1.0


def _separate(mask: np.ndarray, min_elongation: float) -> list[np.ndarray]:
    """Touching fish: a watershed on the distance transform from the region's distinct thick cores
    (each fish's widest part; a fish less than ~0.7 as wide as its neighbour is not split off), if a
    neck narrower than the cores joins them. Kept only if every sizeable part is fish-shaped; else one region."""
    dist = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    top = float(dist.max())
    if top < 2:
        return [mask]
    cores = (dist > 0.7 * top).astype(np.uint8)
    n, markers = cv2.connectedComponents(cores)
    if n <= 2:
        return [mask]
    markers = markers.astype(np.int32)
    markers[mask == 0] = n            # the outside is its own basin
    relief = cv2.cvtColor(np.uint8(255 - np.clip(dist / top * 255, 0, 255)), cv2.COLOR_GRAY2BGR)
    cv2.watershed(relief, markers)
    neck = dist[(markers == -1) & (mask > 0)]
    peaks = [float(dist[markers == j].max(initial=0)) for j in range(1, n)]
    if neck.size and neck.max() > 0.75 * min(peaks):
        return [mask]                 # no neck between the cores: one fish with a broken plateau
    area = float(mask.sum())
    parts = [((markers == j) & (mask > 0)).astype(np.uint8) for j in range(1, n)]
    parts = [_trim(m) for m in parts]
    parts = [m for m in parts if m.sum() > 0.1 * area]
    if len(parts) < 2 or any(_elongation(m) < min_elongation for m in parts):
        return [mask]
    if not _fish_each(parts, area):
        return [mask]
    return parts


def _fish_each(parts: list[np.ndarray], area: float) -> bool:
    """Whether the watershed's parts are fish each, not one fish cut at its peduncle from its own
    broad forked tail: the parts are of like length (``MIN_PART_LENGTH``), alike in how solid they
    are (a body without its tail is solid, a tail's lobes are not: ``MAX_SOLIDITY_GAP``), and
    between them hold most of the region (``MIN_PARTS_COVER``; trimming one fish's contact strip
    leaves ~0.85). Drawn forked fish (bench/diag_surface_drawn.py, 60 tanks, seeds 1000+ / 3000+):
    right 286 -> 399 / 274 -> 387, precision 0.944 -> 0.993 / 0.958 -> 0.995; renders as before."""
    lengths = [_moment_length(m)[1] for m in parts]
    solid = [_solidity(m) for m in parts]
    return (min(lengths) >= MIN_PART_LENGTH * max(lengths) and max(solid) - min(solid) <= MAX_SOLIDITY_GAP
            and sum(float(m.sum()) for m in parts) >= MIN_PARTS_COVER * area)


def _cut_at_waist(mask: np.ndarray, min_elongation: float, slices: int = 24) -> list[np.ndarray]:
    """Fish touching end to end (a snout against a tail): the width profile along the axis has a
    waist in its middle quarter narrower than 0.4 of the widest slice on *both* sides of it; the region
    is cut across the axis there if both pieces are fish-shaped. (One fish's narrowest part, the
    caudal peduncle, lies in its last quarter, and its tail alone is not fish-shaped.)"""
    ys, xs = np.nonzero(mask)
    if len(xs) < 40:
        return [mask]
    pts = np.c_[xs, ys].astype(np.float64)
    c = pts.mean(axis=0)
    e = np.linalg.eigh(np.cov((pts - c).T))[1][:, 1]
    s = (pts - c) @ e
    lo, hi = s.min(), s.max()
    k = np.clip(((s - lo) / max(hi - lo, 1e-9) * slices).astype(int), 0, slices - 1)
    width = np.bincount(k, minlength=slices).astype(float)
    inner = np.arange(int(0.38 * slices), int(np.ceil(0.62 * slices)))
    j = int(inner[np.argmin(width[inner])])
    if not (width[j] < 0.4 * width[:j].max() and width[j] < 0.4 * width[j + 1:].max()):
        return [mask]
    cut = lo + (j + 0.5) * (hi - lo) / slices
    parts = []
    for side in (s < cut, s >= cut):
        m = np.zeros_like(mask)
        m[ys[side], xs[side]] = 1
        n, lab, stats, _ = regions(m)
        if n > 1:
            parts.append((lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8))
    if len(parts) < 2 or any(_elongation(m) < min_elongation for m in parts):
        return [mask]
    return parts


def _trim(part: np.ndarray) -> np.ndarray:
    """A watershed part without the thin strip of its neighbour's flank that the flood can take
    along the contact: an opening finds the part's own body, the part is kept within reach of it
    (so its snout tip, thinner than the opening, stays)."""
    r = max(2, int(0.25 * cv2.distanceTransform(part, cv2.DIST_L2, 3).max()))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    body = cv2.morphologyEx(part, cv2.MORPH_OPEN, disk)
    reach = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 3, 2 * r + 3))
    kept = part & cv2.dilate(body, reach)
    n, lab, stats, _ = regions(kept)
    if n <= 1:
        return kept
    return (lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)


def _silhouette(con: np.ndarray, part: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray | None]:
    """The body part with the pale fins joined to it (contrast above ``level``, within a quarter of
    the body's length of it): the caudal fin is translucent, fainter than the body."""
    ys, xs = np.nonzero(part)
    reach = int(np.ceil(0.25 * max(np.ptp(xs), np.ptp(ys)))) | 1
    near = cv2.distanceTransform(1 - part, cv2.DIST_L2, 3) <= reach
    low = ((con > level) & near).astype(np.uint8) | part
    n, lab = cv2.connectedComponents(low, connectivity=8)
    own = np.bincount(lab[part > 0], minlength=n)
    own[0] = 0
    return _fill((lab == int(own.argmax())).astype(np.uint8))


def find_regions(c: Contrast, p: RegionParams = RegionParams()) -> list[Region]:
    """Candidate fish regions of one image (see module docstring): fish darker than the floor, then
    fish lighter than it (a pale fish over a dark floor)."""
    return _regions(c, p, 1.0) + _regions(c, p, -1.0)


def _regions(c: Contrast, p: RegionParams, sign: float) -> list[Region]:
    labels, stats, keep, s = _grow(c, p, sign)
    H, W = c.full.shape
    diag = float(np.hypot(H, W))
    min_len, max_len = p.min_length_frac * diag, p.max_length_frac * diag
    out: list[Region] = []
    for k in keep:
        x, y, w, h, area = stats[k]
        if max(w, h) * s < 0.5 * min_len or min(w, h) * s > max_len:
            continue
        coarse = (labels[y:y + h, x:x + w] == k).view(np.uint8)
        if _moment_slender(coarse) < p.min_coarse_slender:
            continue                  # a blob at the coarse level (floor texture)
        if sign < 0 and _solidity(coarse) < p.min_coarse_solidity:
            continue                  # a ragged light patch: lamp glitter on the ripples (dark regions
                                      # are not asked: fish touching each other are ragged too)
        m = int(np.ceil(0.3 * max(w, h) * s + 4))
        u0, v0 = max(int(x * s) - m, 0), max(int(y * s) - m, 0)
        u1, v1 = min(int((x + w) * s) + m, W), min(int((y + h) * s) + m, H)
        floor = c.floor_full[v0:v1, u0:u1]
        img = c.full[v0:v1, u0:u1].astype(np.float32)
        con = sign * (1.0 - img / floor)
        lab = labels[y:y + h, x:x + w] == k
        core = cv2.resize(lab.astype(np.uint8), (int(w * s), int(h * s)), interpolation=cv2.INTER_NEAREST)
        seed = np.zeros_like(con, dtype=np.uint8)
        cu, cv_ = int(x * s) - u0, int(y * s) - v0
        seed[cv_:cv_ + core.shape[0], cu:cu + core.shape[1]] = core[:seed.shape[0] - cv_, :seed.shape[1] - cu]
        vals = con[seed > 0]
        if vals.size < 8 or (sign < 0 and np.median(img[seed > 0]) >= p.glare_level):
            continue
        peak = float(np.percentile(vals, 90))
        edge = (con > p.edge_level * peak).astype(np.uint8)
        glaring = ((img >= 250) | ((img > 1.15 * floor) & (sign > 0))).astype(np.uint8)
        origin = np.array([u0, v0], float)
        for piece in _pieces(edge, seed):
            mask, _ = _fill(piece)
            out += _fish_parts(mask, con, img, glaring, peak, sign, origin, (W, H), p)
    return out


def _pieces(edge: np.ndarray, seed: np.ndarray) -> list[np.ndarray]:
    """The pieces of a region's edge mask tried as fish: each component overlapping the seed by at
    least ``COMPONENT_SHARE`` of the largest overlap."""
    n, lab = cv2.connectedComponents(edge, connectivity=8)
    overlap = np.bincount(lab[seed > 0], minlength=n)
    overlap[0] = 0
    if overlap.max() == 0:
        return []
    return [(lab == j).astype(np.uint8) for j in np.flatnonzero(overlap >= COMPONENT_SHARE * overlap.max())]


def _fish_parts(mask: np.ndarray, con: np.ndarray, img: np.ndarray, glaring: np.ndarray, peak: float,
                sign: float, origin: np.ndarray, size: tuple[int, int], p: RegionParams) -> list[Region]:
    """The fish-shaped parts of one redrawn mask (touching fish separated) as regions."""
    if _moment_slender(mask) < p.min_coarse_slender:  # a blob: no fish, nor fish side by side
        return []
    parts = _separate(mask, p.min_elongation)
    # end to end, two fish are about twice as slender as one (one: ~6)
    parts = [q for w in parts for q in (_cut_at_waist(w, p.min_elongation)
                                        if _moment_slender(w) > p.end_to_end_slender else [w])]
    out = []
    for part in parts:
        part, contour = _fill(part)
        if contour is None or len(contour) < 8:
            continue
        if _moment_slender(part) < 0.65 * p.min_slender:
            continue              # too stout for a fish, by its moments (cheap): spared the shape
                                  # analysis. 4 sd along the axis >= 0.82 of the end-to-end length
                                  # for any fish-like outline (a diamond's 4 sd: 0.816 of it)
        whole, outline = _silhouette(con, part, p.fin_level * peak)
        if _touches(outline, origin, size, p.border_px):
            continue
        ring = cv2.dilate(part, np.ones((3, 3), np.uint8)) - part
        glare = float((ring & glaring).sum() / max(ring.sum(), 1))
        out.append(Region(contour.astype(np.float64) + origin, part, origin, peak, glare,
                          outline.astype(np.float64) + origin, sign, whole, con))
    return out


def _touches(contour: np.ndarray, origin, size, border: int) -> bool:
    u, v = contour[:, 0] + origin[0], contour[:, 1] + origin[1]
    return bool(u.min() < border or v.min() < border or u.max() > size[0] - 1 - border
                or v.max() > size[1] - 1 - border)
