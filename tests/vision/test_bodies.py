"""vision.bodies: the per-body sort and quantiles behind the bodies' ends."""
import numpy as np
import pytest

from vision.bodies import _quantile_sorted, _sorted_by_body


@pytest.mark.parametrize("seed", range(6))
def test_values_sorted_within_each_body_as_lexsort(seed):
    rng = np.random.default_rng(seed)
    B = int(rng.integers(1, 40))
    body = rng.integers(0, B, int(rng.integers(1, 5000)))        # raster order: bodies interleaved
    # ties within a body and across bodies, negative and positive positions along the axis
    t = np.round(rng.normal(0, 40, len(body)), int(rng.integers(0, 3)))
    count = np.bincount(body, minlength=B)                       # some bodies may hold nothing
    got, start = _sorted_by_body(t, body, count)
    assert np.array_equal(got, t[np.lexsort((t, body))])
    assert np.array_equal(start, np.concatenate(([0], np.cumsum(count)[:-1])))


def test_quantiles_of_each_body_as_numpy():
    rng = np.random.default_rng(7)
    body = rng.integers(0, 9, 3000)
    t = rng.normal(0, 25, len(body))
    count = np.bincount(body, minlength=9)
    srt, start = _sorted_by_body(t, body, count)
    for q in (0.0, 0.002, 0.5, 0.998, 1.0):
        want = [np.quantile(t[body == b], q) for b in range(9)]
        assert np.allclose(_quantile_sorted(srt, start, count, q), want, rtol=0, atol=1e-9)
