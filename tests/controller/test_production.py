"""Production figures between surveys, from their definitions (controller/production.py)."""
from __future__ import annotations

import math

import pytest

from controller.production import SurveyPoint, days_to, interval, stock_at, weight_at

DAY = 86_400.0


def ev(t, tank, count, to_tank=None, kind=None):
    return {"t": t, "tank": tank, "count": count, "to_tank": to_tank,
            "kind": kind or ("transfer" if to_tank else "mortality")}


def test_transfers_in_and_out_count_at_the_weight_the_fish_had_when_they_moved():
    p1 = SurveyPoint(0.0, 50.0, 10.0, 1.5, 40, 1000)
    p2 = SurveyPoint(20 * DAY, 80.0, 10.0, 1.5, 40, 900)
    events = [ev(5 * DAY, "A", 300, "B"),            # out of A
              ev(15 * DAY, "C", 200, "A"),           # into A
              ev(30 * DAY, "A", 999),                # after the second survey: not counted
              ev(10 * DAY, "B", 50)]                 # another tank's
    i = interval(p1, p2, 40_000.0, events, "A")
    w5, w15 = 50 * (80 / 50) ** 0.25, 50 * (80 / 50) ** 0.75
    gain = 900 * 80 - 1000 * 50 + 300 * w5 - 200 * w15
    assert i.gain_g == pytest.approx(gain) and i.fcr == pytest.approx(40_000 / gain)
    assert i.sgr_pct == pytest.approx(100 * math.log(1.6) / 20)
    assert stock_at(1000, events, "A", 6 * DAY) == 700 and stock_at(1000, events, "A", 16 * DAY) == 900
    assert stock_at(500, events, "B", 6 * DAY) == 800 and stock_at(500, events, "B", 11 * DAY) == 750


def test_the_net_fcr_leaves_out_the_growth_of_the_fish_that_died_not_of_those_harvested():
    p1 = SurveyPoint(0.0, 50.0, 10.0, 1.5, 40, 1000)
    p2 = SurveyPoint(20 * DAY, 80.0, 10.0, 1.5, 40, 880)
    events = [ev(10 * DAY, "A", 20), ev(15 * DAY, "A", 100, kind="harvest"), ev(12 * DAY, "B", 7)]
    i = interval(p1, p2, 40_000.0, events, "A")
    w10, w15 = 50 * (80 / 50) ** 0.5, 50 * (80 / 50) ** 0.75
    gain = 880 * 80 - 1000 * 50 + 20 * w10 + 100 * w15
    assert i.fcr == pytest.approx(40_000 / gain) and i.died_g == pytest.approx(20 * w10)
    assert i.fcr_net == pytest.approx(40_000 / (gain - 20 * w10)) and i.fcr_net > i.fcr
    none_died = interval(p1, p2, 40_000.0, events[1:], "A")
    assert none_died.fcr_net == none_died.fcr and none_died.died_g == 0.0
    # more fish died than the tank kept of its growth: a conversion, but no net one
    worse = interval(p1, SurveyPoint(20 * DAY, 80.0, 10.0, 1.5, 40, 450), 40_000.0, [ev(10 * DAY, "A", 550)], "A")
    assert worse.fcr is not None and worse.fcr_net is None
    from controller.cli.report_cmd import _net
    assert _net(worse.__dict__) == ", net n/a (no gain kept)" and _net(none_died.__dict__) == ""


def test_a_loss_is_no_conversion_and_shrinking_fish_never_reach_a_target():
    p1 = SurveyPoint(0.0, 50.0, 10.0, 1.5, 40, 1000)
    p2 = SurveyPoint(10 * DAY, 45.0, 10.0, 1.5, 40, 1000)
    i = interval(p1, p2, 5000.0, [], "A")
    assert i.gain_g < 0 and i.fcr is None and i.sgr_pct < 0
    assert days_to(400.0, 45.0, i.sgr_pct) is None and days_to(40.0, 45.0, i.sgr_pct) == 0.0
    with pytest.raises(ValueError):
        interval(p2, p1, 0.0, [], "A")


def test_weight_between_surveys_grows_exponentially_from_one_mean_to_the_next():
    p1, p2 = SurveyPoint(0.0, 10.0, 0, 1, 1, 1), SurveyPoint(10.0, 40.0, 0, 1, 1, 1)
    assert weight_at(0.0, p1, p2) == 10.0 and weight_at(10.0, p1, p2) == pytest.approx(40.0)
    assert weight_at(5.0, p1, p2) == pytest.approx(20.0) and weight_at(99.0, p1, p2) == pytest.approx(40.0)
