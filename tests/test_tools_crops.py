"""The learned locators' training crops (tools/fork_net_data.py's ``Crops``): a crop taken with the
other handedness (``side`` -1, as ``snout_net_data.py --upright`` takes those of fish heading one
way) is the same crop mirrored across its axis, its v and turn labels negated with it; the rest of
its labels stay."""
from __future__ import annotations

import numpy as np

from devices.sim.fish_scene import underwater_scene
from tools.fork_net_data import Crops
from vision.fins import Fins
from vision.fork import pyramid


def test_a_crop_of_the_other_handedness_is_its_mirror_with_its_labels_turned():
    sc = underwater_scene(np.random.default_rng(100123))
    pyr = pyramid(sc.left)
    rng = np.random.default_rng(1)
    n = 12
    h = Fins(rng.uniform([200, 200], [1000, 700], (n, 2)), rng.uniform(-np.pi, np.pi, n), rng.uniform(20, 80, n),
             np.zeros(n), np.zeros(n))
    label = tuple(rng.uniform(-1, 1, n) for _ in range(5))
    keep = np.ones(n, bool)
    keep[3] = False
    side = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    plain, turned = Crops(), Crops()
    plain.add(pyr, h, keep, label, (100123, 0, 1))
    turned.add(pyr, h, keep, label, (100123, 0, 1), side)
    x0, x1 = plain.x[0].astype(int), turned.x[0].astype(int)
    y0, y1 = plain.y[0], turned.y[0]
    s = side[keep]
    assert len(x0) == len(x1) == n - 1
    same, mirrored = s > 0, s < 0
    assert np.array_equal(x0[same], x1[same]) and np.array_equal(y0[same], y1[same])
    # rows run across the axis: the other handedness reads them the other way round (to the
    # grid's last bit of rounding)
    assert np.abs(x0[mirrored][:, ::-1] - x1[mirrored]).max() <= 1
    assert not np.array_equal(x0[mirrored], x1[mirrored])
    assert np.allclose(y1[mirrored][:, 2:4], -y0[mirrored][:, 2:4])
    assert np.array_equal(y1[mirrored][:, [0, 1, 4]], y0[mirrored][:, [0, 1, 4]])
