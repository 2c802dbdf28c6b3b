"""The simulated stock: the growth and deaths a grow-out run is judged by follow the model's words."""
import math

import numpy as np
import pytest

from controller.config import load_config
from devices.sim.fish import SimFishParams, SimTank
from devices.sim.stock import DAY_S, SimStock, SimStockParams
from devices.sim.truth import TruthLog

T0 = 1_780_000_000.0


def stock(count=20_000, mean=18.0, seed=1, **params):
    return SimStock("T1", count, mean, SimStockParams(**params), np.random.default_rng(seed), T0)


def test_every_gram_eaten_makes_one_over_fcr_of_fish():
    s = stock(mortality_pct_day=0.0, fcr=1.25)
    b0 = s.biomass_g
    assert s.mean_g == pytest.approx(18.0) and b0 == pytest.approx(20_000 * 18.0)
    fed = 0.0
    for day in range(30):
        for meal in range(8):
            g = 300.0 + 40 * meal
            s.feed(g, T0 + day * DAY_S + meal * 3600)
            fed += g
    assert s.biomass_g - b0 == pytest.approx(fed / 1.25, rel=1e-9)
    assert s.eaten_g == pytest.approx(fed)


def test_the_spread_starts_as_configured_and_grows_only_with_the_fish_own_factors():
    even = stock(mortality_pct_day=0.0, growth_cv_pct=0.0, weight_cv_pct=20.0, sample=20_000)
    spread = stock(mortality_pct_day=0.0, growth_cv_pct=30.0, weight_cv_pct=20.0, sample=20_000)
    cv = lambda s: s.w.std() / s.w.mean()                                     # noqa: E731
    assert cv(even) == pytest.approx(0.20, abs=0.01) and cv(spread) == pytest.approx(0.20, abs=0.01)
    for day in range(60):
        for s in (even, spread):
            s.feed(s.biomass_g * 0.02, T0 + day * DAY_S)                      # 2 % of biomass a day
    assert cv(even) == pytest.approx(0.20, abs=0.01)        # everyone grew by the same share
    assert cv(spread) > 0.25
    # the stock's specific growth rate is the model's: biomass x (1 + 0.02 / fcr) a day
    assert even.mean_g == pytest.approx(18.0 * (1 + 0.02 / 1.4) ** 60, rel=1e-9)


def test_deaths_follow_the_rate_and_the_sample_follows_the_count():
    truth = TruthLog(None)
    s = SimStock("T1", 20_000, 18.0, SimStockParams(mortality_pct_day=0.5, sample=2000), np.random.default_rng(3),
                 T0, truth)
    s.advance(T0 + 100 * DAY_S)
    expect = 20_000 * math.exp(-0.005 * 100)
    sd = math.sqrt(20_000 * math.exp(-0.5) * (1 - math.exp(-0.5)))
    assert abs(s.count - expect) < 4 * sd
    assert len(s.w) == pytest.approx(2000 * s.count / 20_000, rel=0.1)
    deaths = [r for r in truth.records if r["kind"] == "mortality"]
    assert sum(r["count"] for r in deaths) == 20_000 - s.count == s.deaths
    days = [r for r in truth.records if r["kind"] == "stock"]
    counts = [r["count"] for r in days]
    assert len(days) == 100 and counts == sorted(counts, reverse=True) and counts[-1] >= s.count
    assert all(r["t"] % DAY_S == 0 for r in days)          # each closes a farm day (UTC)


def test_the_food_over_the_gain_with_the_dead_fishs_weight_is_the_fcr_and_without_it_more():
    truth = TruthLog(None)
    s = SimStock("T1", 20_000, 18.0, SimStockParams(mortality_pct_day=0.5, sample=20_000, fcr=1.4),
                 np.random.default_rng(5), T0, truth)
    b0 = s.biomass_g
    for day in range(42):
        for meal in range(4):
            s.feed(s.biomass_g * 0.005, T0 + day * DAY_S + (meal + 1) * 4 * 3600)
    s.advance((math.floor(T0 / DAY_S) + 43) * DAY_S)        # to a farm day's end: its record written
    died = [r["died_g"] for r in truth.records if r["kind"] == "stock"]
    assert died == sorted(died) and died[-1] == pytest.approx(s.died_g, abs=0.1) and s.deaths > 3000
    # the dead fish weighed what the stock's mean was when they died: between the start's and the end's
    assert 18.0 * s.deaths < s.died_g < s.mean_g * s.deaths
    assert s.eaten_g / (s.biomass_g - b0 + s.died_g) == pytest.approx(1.4, rel=0.01)      # biological
    assert s.eaten_g / (s.biomass_g - b0) > 1.4 * 1.1                                      # net: the dead lost


def test_a_tank_asks_for_more_as_its_fish_grow():
    cfg = load_config("config/farm.toml")
    tank = SimTank(cfg.tank("T1"), SimFishParams(), np.random.default_rng(0))
    before = tank.appetite_g_s
    tank.stock = SimStock("T1", cfg.tank("T1").stock, cfg.tank("T1").mean_weight_g,
                          SimStockParams(mortality_pct_day=0.0), np.random.default_rng(0), T0)
    assert tank.appetite_g_s == pytest.approx(before)
    tank.feed(5000.0, T0 + 10)
    b0 = cfg.tank("T1").stock * cfg.tank("T1").mean_weight_g
    assert tank.appetite_g_s == pytest.approx(before * (b0 + 5000 / 1.4) / b0)


def test_bad_stock_parameters_are_refused():
    with pytest.raises(ValueError):
        SimStockParams(fcr=0.0)
    with pytest.raises(ValueError):
        SimStockParams(samples=10)
