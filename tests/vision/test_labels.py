"""vision.labels.regions is OpenCV's default 8-connected labelling with statistics, only cheaper:
the same count, labels, statistics and centroids on masks of every kind (random speckle at many
densities, thin lines and rings that join only diagonally, blobs touching the border, empty and
full masks, odd sizes)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vision.labels import regions


def default(mask):
    return cv2.connectedComponentsWithStats(mask, connectivity=8)


def masks():
    rng = np.random.default_rng(3)
    out = [np.zeros((240, 320), np.uint8), np.ones((240, 320), np.uint8), np.ones((1, 1), np.uint8)]
    for p in (0.05, 0.3, 0.5, 0.6, 0.9):
        for shape in ((240, 320), (17, 333), (101, 3)):
            out.append((rng.random(shape) < p).astype(np.uint8))
    diag = np.zeros((64, 64), np.uint8)
    diag[np.arange(64), np.arange(64)] = 1                        # joined only through corners
    diag[np.arange(63), np.arange(1, 64)[::-1]] = 255             # any non-zero value is foreground
    rings = np.zeros((200, 300), np.uint8)
    for _ in range(12):
        cv2.circle(rings, (int(rng.integers(0, 300)), int(rng.integers(0, 200))), int(rng.integers(3, 60)), 1, 1)
        cv2.ellipse(rings, (int(rng.integers(0, 300)), int(rng.integers(0, 200))),
                    (int(rng.integers(5, 90)), int(rng.integers(2, 20))), float(rng.uniform(0, 180)), 0, 360, 1, -1)
    return out + [diag, rings, np.ascontiguousarray(rings[::-1, ::-1])]


@pytest.mark.parametrize("k", range(len(masks())))
def test_regions_are_opencvs_default_labelling(k):
    m = masks()[k]
    n, lab, stats, cent = regions(m)
    n0, lab0, stats0, cent0 = default(m)
    assert n == n0
    assert np.array_equal(lab, lab0)
    assert np.array_equal(stats, stats0)
    assert np.allclose(cent, cent0, equal_nan=True)
