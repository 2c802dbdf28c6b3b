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


@pytest.mark.parametrize(("jump", "flagged"), [(1.001, False), (1.06, False), (0.94, False), (1.35, True),
                                               (0.72, True)])
def test_a_survey_is_weighed_against_the_growth_of_the_surveys_before_it(tmp_path, jump, flagged):
    """Four weekly surveys on W = 20·e^(0.02·day) (on the line: no scatter to scale by), then a fifth
    at ``jump`` times the curve. The band is worked out here: the weighted fit's variance of ln W at
    the fifth survey's day (numpy's polyfit, unscaled covariance) with the survey's own (CV/√n)²,
    times OFF_GROWTH_Z standard errors."""
    import numpy as np

    from controller.production import OFF_GROWTH_Z, against_growth
    from controller.store import Store
    store = Store(tmp_path / "ledger.db")
    day, t0, n, cv = 86_400.0, 1_780_000_000.0, 60, 20.0
    days = [0.0, 7.0, 14.0, 21.0]
    for d in days:
        mean = 20.0 * math.exp(0.02 * d)
        # a survey of 60 fish whose CV (sample sd over mean) is 20 %: weights symmetric about the mean
        spread = 0.2 * mean * math.sqrt((n - 1) / n)
        store.add_survey("T1", t0 + d * day, "sparus_aurata", "x", [10.0] * n,
                         [mean + spread * (1 if i % 2 else -1) for i in range(n)])
    w5 = 20.0 * math.exp(0.02 * 28.0) * jump
    sid = store.add_survey("T1", t0 + 28 * day, "sparus_aurata", "x", [10.0] * n,
                           [w5 * (1 + 0.2 * math.sqrt((n - 1) / n) * (1 if i % 2 else -1)) for i in range(n)])
    survey = next(r for r in store.surveys("T1") if r.id == sid)
    got = against_growth(store, "T1", survey, 56.0)
    se = cv / 100 / math.sqrt(n)
    _, cov = np.polyfit(days, np.log([20.0 * math.exp(0.02 * d) for d in days]), 1, w=[1 / se] * 4, cov="unscaled")
    fit_var = np.array([28.0, 1.0]) @ cov @ np.array([28.0, 1.0])
    band = OFF_GROWTH_Z * math.sqrt(fit_var + se**2)
    assert got["surveys"] == 4 and got["off"] is flagged
    assert got["off_pct"] == pytest.approx(100 * (jump - 1), abs=1e-6)
    assert got["band_pct"] == pytest.approx(100 * math.expm1(math.copysign(band, jump - 1)), rel=1e-6)
    assert got["fitted_g"] == pytest.approx(20.0 * math.exp(0.02 * 28.0), rel=1e-9)


def test_no_growth_to_weigh_a_survey_against_before_two_surveys(tmp_path):
    from controller.production import against_growth
    from controller.store import Store
    store = Store(tmp_path / "ledger.db")
    store.add_survey("T1", 1_780_000_000.0, "sparus_aurata", "x", [10.0] * 5, [20.0] * 5)
    sid = store.add_survey("T1", 1_780_600_000.0, "sparus_aurata", "x", [10.0] * 5, [80.0] * 5)
    assert against_growth(store, "T1", next(r for r in store.surveys("T1") if r.id == sid), 56.0) is None
