"""Sub-pixel conventions of the fork locator: a small fish's fork, drawn with its exact area
coverage at a known sub-pixel point, is located there without a bias along the axis (a fixed
offset in px is a length bias that grows as fish shrink in the image: issues 7 and 10)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.vision.fish_drawing import covered, fish_outline
from vision.fins import SPAN_OF_FL, Fins
from vision.fork import locate_forks, pyramid


def fish_image(rng: np.random.Generator, length_px: float, size: int = 160):
    """A fish of the contract's outline, fork at a random sub-pixel point near the middle, heading
    anywhere, blurred and noisy: (image uint8, fork xy, angle fork -> snout)."""
    fork = size / 2 + rng.uniform(-0.5, 0.5, 2)
    angle = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(angle), np.sin(angle)
    out = fish_outline() * length_px
    pts = fork + out[:, :1] * [c, s] + out[:, 1:] * [-s, c]
    img = 70.0 + 90.0 * covered((size, size), pts)
    img = cv2.GaussianBlur(img, (0, 0), 0.7) + rng.normal(0, 2.0, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), fork, angle


@pytest.mark.parametrize("length_px", [45.0, 70.0])
def test_small_fish_fork_located_without_bias_along_the_axis(length_px):
    rng = np.random.default_rng(int(length_px))
    along, across = [], []
    for _ in range(30):
        img, fork, angle = fish_image(rng, length_px)
        fins = Fins(fork[None].copy(), np.array([angle]), np.array([SPAN_OF_FL * length_px]), np.zeros(1), np.ones(1))
        pyr = pyramid(img)
        first = locate_forks(pyr, fins)
        assert first.ok[0]
        again = locate_forks(pyr, first.fins)
        assert again.ok[0]
        e = again.fins.xy[0] - fork
        along.append(-(e @ [np.cos(angle), np.sin(angle)]))         # + behind the notch
        across.append(e @ [-np.sin(angle), np.cos(angle)])
    along = np.array(along)
    assert np.abs(along).max() < 0.03 * length_px
    # 0.2 px: 0.4-0.9 % of these lengths, of the order of the tail's own sub-pixel rounding
    assert abs(along.mean()) < 0.2
    assert abs(np.mean(across)) < 0.2
