"""Silhouettes against a local background, fork proposals from their outlines and snout tips from
silhouettes: on fish drawn with cv2 (a body with a forked caudal fin) over water
with a vertical gradient and clutter, independent of the renderer."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.vision.fish_drawing import draw_fish_2d, water
from vision.fins import SPAN_OF_FL
from vision.silhouettes import (
    background_distance,
    body_fill,
    components,
    fish_masks,
    outline_forks,
    silhouette_tips,
)

W, H = 640, 480
WORK = 4.0          # full-resolution px per working px


def scene(rng, fish, clutter: bool = False, colour: bool = True):
    """Water (a gradient, noise, optionally dark blobs of reef) with fish (fork xy, angle, length, level)."""
    img = water(H, W, rng)
    if clutter:
        blobs = np.zeros((H, W), np.float32)
        for _ in range(25):
            cv2.circle(blobs, tuple(int(v) for v in rng.uniform([0, 0], [W, H])), int(rng.uniform(5, 25)), 1.0, -1)
        img -= 25.0 * cv2.GaussianBlur(blobs, (0, 0), 3)
    snouts = [draw_fish_2d(img, xy, a, L, v) for xy, a, L, v in fish]
    img = np.clip(img, 0, 255).astype(np.uint8)
    if colour:
        img = cv2.merge([np.clip(img * 1.0, 0, 255).astype(np.uint8), img, (img * 0.6).astype(np.uint8)])
    return img, np.array(snouts)


def small_of(img):
    return cv2.resize(img, (W // 4, H // 4), interpolation=cv2.INTER_AREA)


FISH = [((150.0, 140.0), 0.1, 260.0, 230.0), ((420.0, 330.0), np.pi + 0.2, 220.0, 20.0)]


@pytest.mark.parametrize("colour", [True, False])
@pytest.mark.parametrize("clutter", [False, True])
def test_forks_are_proposed_at_the_notch_of_bright_and_dark_fish(colour, clutter):
    img, _ = scene(np.random.default_rng(1), FISH, clutter, colour)
    z, bg, spread = background_distance(small_of(img))
    assert z.shape == (H // 4, W // 4) and bg.shape[:2] == z.shape and spread.min() > 0
    for fork, _, L, _ in FISH:
        hits = []
        for m in fish_masks(z):
            f, _ = outline_forks(m, WORK, WORK, 20)
            notch = f.score > 1.0
            d = np.linalg.norm(f.xy[notch] - fork, axis=1)
            hits.append(d.min() if len(d) else np.inf)
        assert min(hits) <= 0.05 * L, (fork, hits)


def test_open_water_gives_no_silhouette():
    rng = np.random.default_rng(2)
    img, _ = scene(rng, [])
    z, _, _ = background_distance(small_of(img))
    for m in fish_masks(z):
        f, _ = outline_forks(m, WORK, WORK, 20)
        assert len(f) == 0


def test_snout_tips_are_the_silhouettes_far_ends_and_segments_lie_in_them():
    img, snouts = scene(np.random.default_rng(6), FISH)
    z, _, _ = background_distance(small_of(img))
    comps = components(fish_masks(z))
    forks = np.array([f[0] for f in FISH])
    angles = np.array([f[1] for f in FISH]) + np.radians(8)        # an axis a little off
    spans = SPAN_OF_FL * np.array([f[2] for f in FISH])
    tips = silhouette_tips(comps, WORK, WORK, forks, angles, spans)
    assert tips.shape == (2, len(comps), 2)
    for n, (_, _, L, _) in enumerate(FISH):
        err = np.linalg.norm(tips[n] - snouts[n], axis=1)
        assert np.nanmin(err) <= 0.03 * L
    fill = body_fill(comps, WORK, WORK, forks, snouts)
    assert np.all(fill >= 0.8)
    across = body_fill(comps, WORK, WORK, forks[:1], np.array([[600.0, 60.0]]))     # into open water
    assert across[0] < 0.5
