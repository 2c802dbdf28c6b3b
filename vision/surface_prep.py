"""Pre-processing for the surface setup (nursery tanks seen from above): noise reduction and
illumination compensation by a flat field, giving a *contrast map*: how much darker than the tank
floor under it each pixel is, as a fraction of the floor's brightness.

Why a flat field rather than the paper's per-row compensation (eqs. 11-12, vision/illumination.py):
eqs. 11-12 model sunlight falling off with depth in front of a horizontal underwater camera, row by
row. Lamps at ~45 deg light a tank from one side, so the floor's brightness falls off along a
direction that need not be the image rows, and eq. 12's per-row contrast stretch would amplify
whatever a row holds (a row crossing a lamp's reflection is squeezed, an empty row stretched).
The floor is instead estimated where fish are not: on a coarse copy of the image (1/8 linear scale
or so), an opening removes bright structures narrower than the kernel (surface reflections of the
lamps) and a closing then removes dark ones (fish); what is left, smoothed and scaled back, is the
floor under the fish. Dividing by it cancels
any smooth illumination field, multiplicative like light is.

Everything scales with the image: the working level is chosen from the image width, and the
background kernel from the coarse image's size.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def grey(img: np.ndarray) -> np.ndarray:
    """uint8 grey (H, W) of a grey or BGR/BGRA uint8 image."""
    img = np.asarray(img)
    if img.ndim == 3:
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(img, code)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


@dataclass
class Contrast:
    """A contrast map and what it was made from."""

    full: np.ndarray          # (H, W) uint8 grey, lightly denoised
    floor_full: np.ndarray    # (H, W) float32 floor brightness under each pixel
    work: np.ndarray          # (h, w) float32 contrast map at the working level: 1 - I / floor
    scale: float              # full-resolution pixels per working pixel
    noise: float              # robust standard deviation of ``work`` over the floor


def _odd(n: float) -> int:
    n = max(int(round(n)), 3)
    return n if n % 2 else n + 1


def working_scale(width: int, target_width: int = 640) -> int:
    """Power-of-two reduction bringing the width to about ``target_width`` (at least 1)."""
    s = 1
    while width / (2 * s) >= target_width * 0.75:
        s *= 2
    return s


# A colour picture's contrast is its most unlike channel's (``_most_unlike_floor``), not the grey
# level's. Measured (bench_survey_surface, 90 tanks, seeds 1000 / 5000): recall 0.427 / 0.491 ->
# 0.483 / 0.524, precision 0.898 / 0.911 -> 0.919 / 0.883; ~11 ms more an image (README, *Colour*)
COLOUR_CONTRAST = True


def _floor(full: np.ndarray, bg_fraction: float) -> np.ndarray:
    """The floor under each pixel of a (H, W) or (H, W, C) uint8 image, float32 of its shape:
    opening (reflections out) then closing (fish out) on a coarse copy, smoothed, scaled back."""
    H, W = full.shape[:2]
    cw = max(W // 8, 16)
    ch = max(int(round(H * cw / W)), 8)
    coarse = cv2.resize(full, (cw, ch), interpolation=cv2.INTER_AREA)
    k = _odd(bg_fraction * cw)
    kern = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    floor = cv2.morphologyEx(cv2.morphologyEx(coarse, cv2.MORPH_OPEN, kern), cv2.MORPH_CLOSE, kern)
    floor = cv2.GaussianBlur(floor.astype(np.float32), (0, 0), k / 3)
    return np.maximum(floor, 4.0)


def _most_unlike_floor(img: np.ndarray, g: np.ndarray, bg_fraction: float) -> np.ndarray:
    """A colour image as the grey one whose contrast with its floor is, at each pixel, that of the
    colour channel most unlike the floor there (darker or lighter), under the grey floor. A fish
    the grey level hardly tells from the floor (a brown back over blue water, a green one over
    sand) differs in one of the channels."""
    H, W = g.shape
    size = (W, H)
    grey_floor = cv2.resize(_floor(g, bg_fraction), size, interpolation=cv2.INTER_LINEAR)
    bgr = np.ascontiguousarray(img[..., :3])
    per_floor = cv2.split(cv2.resize(1.0 / _floor(bgr, bg_fraction), size, interpolation=cv2.INTER_LINEAR))
    best = most = None                  # the ratio to the floor farthest from 1, and its distance
    for plane, inv in zip(cv2.split(bgr), per_floor, strict=True):
        ratio = cv2.multiply(plane, inv, dtype=cv2.CV_32F)
        off = cv2.absdiff(ratio, 1.0)
        if best is None:
            best, most = ratio, off
            continue
        cv2.copyTo(ratio, cv2.compare(off, most, cv2.CMP_GT), best)
        cv2.max(most, off, most)
    return cv2.multiply(grey_floor, best, dtype=cv2.CV_8U)


def contrast_map(img: np.ndarray, *, bg_fraction: float = 1 / 10, target_width: int = 640) -> Contrast:
    """Contrast map of a grey/BGR image. ``bg_fraction``: the floor kernel as a fraction of the
    image width; it must exceed the widest fish seen from above (fish are ~1/5 as wide as long).
    A colour image's contrast is its most unlike channel's at each pixel (``_most_unlike_floor``)."""
    img = np.asarray(img)
    g = grey(img)
    if COLOUR_CONTRAST and img.ndim == 3 and img.shape[2] >= 3 and img.dtype == np.uint8:
        g = _most_unlike_floor(img, g, bg_fraction)
    H, W = g.shape
    full = cv2.GaussianBlur(g, (3, 3), 0)
    s = working_scale(W, target_width)
    work_img = full
    for _ in range(int(np.log2(s))):
        work_img = cv2.pyrDown(work_img)
    floor = _floor(full, bg_fraction)
    h, w = work_img.shape
    floor_work = cv2.resize(floor, (w, h), interpolation=cv2.INTER_LINEAR)
    floor_full = cv2.resize(floor, (W, H), interpolation=cv2.INTER_LINEAR)
    work = 1.0 - work_img.astype(np.float32) / floor_work
    sample = work[::4, ::4]
    med = float(np.median(sample))
    noise = float(1.4826 * np.median(np.abs(sample - med)))
    return Contrast(full, floor_full, work, float(s), max(noise, 1e-3))
