"""Pre-processing (paper eqs. 11-12): every row to the reference mean and contrast, robust to a glint,
flat rows guarded; the water distance makes fish bright whatever their polarity or the water's colour."""
from __future__ import annotations

import numpy as np
import pytest

from tests.vision.fish_drawing import draw_fish_2d, water
from vision.illumination import compensate_rows, denoise, row_stats, to_grey, water_distance


def graded(rng, h=120, w=200):
    """Rows whose mean falls from 200 to 40 and whose contrast shrinks with it (sunlit top, dark bottom)."""
    mean = np.linspace(200, 40, h)[:, None]
    spread = np.linspace(60, 8, h)[:, None]
    return (mean + spread * rng.uniform(-1, 1, (h, w))).astype(np.float32)


@pytest.mark.parametrize("contrast", ["percentile", "range"])
def test_every_row_gets_the_reference_mean_and_contrast(contrast):
    img = graded(np.random.default_rng(1))
    out = compensate_rows(img, mi_ref=120, c_ref=80, contrast=contrast, clip=False)
    mean, c = row_stats(out, contrast)
    assert np.allclose(mean, 120, atol=1e-3)
    assert np.allclose(c, 80, rtol=1e-3)


def test_paper_form_is_max_minus_min():
    img = np.array([[10, 20, 30, 40], [0, 0, 100, 100]], np.float32)
    mean, c = row_stats(img, "range")
    assert mean.tolist() == [25, 50] and c.tolist() == [30, 100]
    out = compensate_rows(img, 120, 130, "range", clip=False)
    assert np.allclose(out[1], [55, 55, 185, 185])           # 130/100 (f - 50) + 120


def test_a_glint_does_not_flatten_its_row_with_the_percentile_contrast():
    rng = np.random.default_rng(2)
    img = 100 + 10 * rng.uniform(-1, 1, (2, 400)).astype(np.float32)
    img[1, 17] = 255                                           # one saturated glint on a scale
    for contrast, similar in (("percentile", True), ("range", False)):
        out = compensate_rows(img, 120, 130, contrast, clip=False)
        ratio = np.delete(out[1], 17).std() / out[0].std()    # the rest of the row: squashed or not
        assert (abs(ratio - 1) < 0.2) == similar, (contrast, ratio)


@pytest.mark.parametrize("value", [0.0, 77.0, 255.0])
def test_flat_rows_do_not_divide_by_zero(value):
    img = np.full((5, 50), value, np.float32)
    img[2] = np.linspace(0, 100, 50)
    out = compensate_rows(img, 120, 130)
    assert np.all(np.isfinite(out))
    assert np.allclose(out[[0, 1, 3, 4]], 120)                 # a flat row goes to the reference mean


def test_grey_and_colour_inputs():
    rng = np.random.default_rng(3)
    grey = rng.integers(0, 255, (40, 60), dtype=np.uint8)
    assert to_grey(grey) is grey
    assert to_grey(np.dstack([grey] * 3)).shape == (40, 60)
    assert np.array_equal(to_grey(np.dstack([grey] * 3)), grey)
    with pytest.raises(ValueError):
        to_grey(np.zeros((2, 3, 4, 5), np.uint8))
    assert denoise(grey, 0).dtype == np.float32


@pytest.mark.parametrize("fish_value", [30.0, 230.0])
@pytest.mark.parametrize("colour", [False, True])
def test_water_distance_makes_fish_bright_either_polarity(fish_value, colour):
    rng = np.random.default_rng(4)
    img = water(240, 320, rng)
    if colour:         # blue-green water, greyish fish
        img = np.dstack([img * 0.9, img, img * 0.5])
    snout = draw_fish_2d(img, (100, 120), 0.1, 120, fish_value)
    d = water_distance(np.clip(img, 0, 255).astype(np.uint8), 120, 130)
    body = d[118:124, 150:200].mean()
    water_far = np.r_[d[10:40].ravel(), d[200:230].ravel()]
    assert body > np.quantile(water_far, 0.99) * 2, (body, np.quantile(water_far, 0.99))
    assert snout[0] > 200


def test_open_water_rows_are_not_stretched_beyond_the_gain_cap():
    rng = np.random.default_rng(5)
    img = 100 + rng.normal(0, 2, (50, 300)).astype(np.float32)
    paper = compensate_rows(img, 120, 130, clip=False)
    capped = compensate_rows(img, 120, 130, clip=False, max_gain=3)
    assert paper.std() > 10 * img.std()           # eq. (12) as written: noise to full contrast
    assert capped.std() <= 3.01 * img.std()


def test_running_median_is_scipy_median_filter_with_nearest_ends():
    from scipy.ndimage import median_filter

    from vision.illumination import running_median
    rng = np.random.default_rng(3)
    for n, k in ((240, 37), (10, 37), (5, 3), (961, 145)):
        v = rng.normal(size=n).astype(np.float32)
        assert np.array_equal(running_median(v, k), median_filter(v, size=k, mode="nearest"))
