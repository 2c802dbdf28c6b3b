"""The surface setup's contrast map on colour pictures: a fish that differs from the floor in one
colour channel and not in its grey level is a fish (a brown back over blue water)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.vision.test_surface_drawing import floor, outline, place
from vision.surface import detect_fish
from vision.surface_prep import contrast_map

GREY_WEIGHTS = np.array([0.114, 0.587, 0.299])          # OpenCV's BGR -> grey


def _same_grey(floor_bgr: np.ndarray, channel: int, change: float) -> np.ndarray:
    """A colour of the floor's grey level: ``channel`` moved by ``change`` of its value, the other two
    together taking back its share of the grey (their proportions kept)."""
    colour = floor_bgr.astype(float).copy()
    change *= colour[channel]
    colour[channel] += change
    others = [c for c in range(3) if c != channel]
    back = GREY_WEIGHTS[channel] * change / (GREY_WEIGHTS[others] @ colour[others])
    colour[others] *= 1 - back
    assert GREY_WEIGHTS @ colour == pytest.approx(GREY_WEIGHTS @ floor_bgr, abs=1e-6)
    assert np.all((colour >= 5) & (colour <= 250))
    return colour


def _tank(floor_bgr, fish_bgr, snout, heading, length, rng):
    """A colour tank: the floor's colour lit from one side, one fish of ``fish_bgr`` lit alike,
    anti-aliased, blurred a little, with sensor noise in each channel."""
    light = floor(rng=None, gradient=(1.0, 0.75))[..., None]               # (H, W, 1) shading
    mask = np.zeros(light.shape[:2], np.uint8)
    cv2.fillPoly(mask, [np.round(place(outline(length), snout, heading) * 16).astype(np.int32)], 255,
                 cv2.LINE_AA, shift=4)
    cover = mask.astype(np.float32)[..., None] / 255
    img = light * (np.asarray(floor_bgr, np.float32) * (1 - cover) + np.asarray(fish_bgr, np.float32) * cover)
    img = cv2.GaussianBlur(img, (0, 0), 0.8) + rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


FLOORS = {"blue water": np.array([150.0, 110.0, 60.0]), "sand": np.array([100.0, 140.0, 160.0]),
          "green": np.array([100.0, 150.0, 90.0])}


@pytest.mark.parametrize("where", sorted(FLOORS))
@pytest.mark.parametrize("channel,change", [(0, -0.45), (0, 0.4), (1, -0.35), (1, 0.3), (2, -0.45), (2, 0.4)])
def test_a_fish_of_the_floor_s_grey_level_is_found_by_its_colour(where, channel, change):
    rng = np.random.default_rng(channel * 1000 + int(100 * change) + 100)
    fish = _same_grey(FLOORS[where], channel, change)
    L, snout, heading = 150.0, np.array([560.0, 430.0]), np.radians(25 + 40 * channel)
    img = _tank(FLOORS[where], fish, snout, heading, L, rng)
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    assert detect_fish(grey) == []                     # the grey level alone shows no fish: the premise
    found = detect_fish(img)
    assert len(found) == 1, [(f.snout, f.fork) for f in found]
    fork = snout + L * np.array([np.cos(heading), np.sin(heading)])
    assert np.linalg.norm(found[0].snout - snout) < 0.03 * L
    assert np.linalg.norm(found[0].fork - fork) < 0.03 * L


def test_a_grey_picture_stored_in_colour_has_the_grey_picture_s_contrast():
    rng = np.random.default_rng(5)
    img = floor(rng=rng)
    mask = np.zeros(img.shape, np.uint8)
    cv2.fillPoly(mask, [np.round(place(outline(140.0), np.array([500.0, 400.0]), 0.7) * 16).astype(np.int32)],
                 255, cv2.LINE_AA, shift=4)
    img = np.clip(img * (1 - 0.4 * mask / 255), 0, 255).astype(np.uint8)
    grey, colour = contrast_map(img), contrast_map(cv2.merge([img, img, img]))
    assert np.abs(colour.full.astype(int) - grey.full).max() <= 1           # rounding only
    assert colour.noise == pytest.approx(grey.noise, rel=0.05)
    a, b = detect_fish(img), detect_fish(cv2.merge([img, img, img]))
    assert len(a) == len(b) == 1
    assert np.linalg.norm(a[0].snout - b[0].snout) < 0.5 and np.linalg.norm(a[0].fork - b[0].fork) < 0.5


def test_a_colour_picture_with_an_alpha_channel_is_read_by_its_colours():
    rng = np.random.default_rng(9)
    fish = _same_grey(FLOORS["sand"], 2, -0.45)
    img = _tank(FLOORS["sand"], fish, np.array([500.0, 500.0]), 0.3, 150.0, rng)
    bgra = cv2.cvtColor(img, cv2.COLOR_BGR2BGRA)
    assert np.array_equal(contrast_map(bgra).full, contrast_map(img).full)
