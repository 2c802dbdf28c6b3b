"""The Gaussian pyramid every sampler reads: a level's pixel j covers full pixels 2j and 2j+1, as
the samplers' (x + 0.5) / 2 - 0.5 assume, so an image's mirror has the mirrored pyramid."""
from __future__ import annotations

import cv2
import numpy as np

from devices.sim.fish_scene import underwater_scene
from vision.fins import half
from vision.fork import pyramid


def test_the_pyramid_of_a_mirror_image_is_the_mirror_of_its_pyramid():
    img = underwater_scene(np.random.default_rng(400000)).left
    for a, b in zip(pyramid(img), pyramid(cv2.flip(img, 1)), strict=True):
        assert np.array_equal(cv2.flip(a, 1), b)


def test_a_pyramid_level_is_where_the_samplers_put_it():
    # a vertical edge between full columns 15 and 16 lies between columns 7 and 8 of the first level,
    # equally far from both (cv2.pyrDown put it at 7.25)
    img = np.zeros((32, 32), np.uint8)
    img[:, 16:] = 200
    row = half(img)[8].astype(float)
    assert abs(row[7] + row[8] - 200) <= 1 and abs(row[6] + row[9] - 200) <= 1
    assert half(np.zeros((31, 33), np.uint8)).shape == (16, 17)
