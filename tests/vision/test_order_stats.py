"""vision.order_stats: numpy's median and quantile, bit for bit, whatever the values."""
import numpy as np
import pytest

from vision import order_stats


def _arrays():
    rng = np.random.default_rng(11)
    yield rng.random(76_800).astype(np.float32) * 40                    # a working image's distances
    yield rng.random(76_801)                                             # odd count, float64
    yield np.round(rng.normal(5, 2, (240, 321)).astype(np.float32), 1)  # 2-D, many ties
    yield np.full(1000, 3.5, np.float32)                                 # all alike
    yield np.array([7.0])                                                # one value
    yield np.array([2.0, -1.0])                                          # two: their mean
    withnan = rng.random(5000)
    withnan[17] = np.nan
    yield withnan                                                        # NaN: numpy's NaN


@pytest.fixture(params=[False, True], ids=["select", "sort_first"])
def either_way(request, monkeypatch):
    """Both ways the module may take, whichever its probe picks on this machine."""
    monkeypatch.setattr(order_stats, "_sort_first", request.param)


@pytest.mark.parametrize("a", list(_arrays()), ids=lambda a: f"{a.dtype}-{a.size}")
def test_median_is_numpys(a, either_way):
    assert np.array_equal(order_stats.median(a), float(np.median(a)), equal_nan=True)


@pytest.mark.parametrize("a", list(_arrays()), ids=lambda a: f"{a.dtype}-{a.size}")
@pytest.mark.parametrize("q", [0.0, 0.001, 0.25, 0.5, 0.9, 0.999, 1.0])
def test_quantile_is_numpys(a, q, either_way):
    assert np.array_equal(order_stats.quantile(a, q), float(np.quantile(a, q)), equal_nan=True)


def test_the_probe_picks_a_way_and_keeps_it(monkeypatch):
    monkeypatch.setattr(order_stats, "_sort_first", None)
    order_stats.median(np.arange(5.0))
    chosen = order_stats._sort_first
    assert isinstance(chosen, bool)
    monkeypatch.setattr(order_stats, "_probe", lambda: pytest.fail("probed twice"))
    assert order_stats.quantile(np.arange(5.0), 0.5) == 2.0
    assert order_stats._sort_first is chosen
