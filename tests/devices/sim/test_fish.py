"""The simulated tank: hunger, episodes, eating, and the surroundings' contacts."""
from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from controller.config import TankConfig
from devices.sim.fish import SimFishParams, SimTank
from devices.sim.truth import TruthLog

T0 = 1_780_000_000.0
TANK = TankConfig(id="T1", stock=2400, mean_weight_g=18, position_m=3.0, sensors=["T1-a", "T1-b"])
APPETITE = 2400 * 18 * 0.025 / 86400                    # g/s at 2.5 % a day


def tank(seed=1, **kw):
    truth = TruthLog(None)
    return SimTank(TANK, SimFishParams(**kw), np.random.default_rng(seed), truth, T0), truth


def kinds(truth, kind):
    return [r for r in truth.records if r["kind"] == kind]


def test_hunger_grows_until_the_fish_ask():
    t, truth = tank(initial_hunger=0.0, turbulence_hz=0.0, bursts_per_hour=0.0)
    assert t.contacts_until(T0 + 4000) == [] and not t.asking
    t.contacts_until(T0 + 6000)
    start = kinds(truth, "episode_start")[0]
    assert start["t"] == pytest.approx(T0 + 60.0 / APPETITE, abs=0.01)
    assert 0.1 <= start["rate_hz"] <= 2.0


def test_feeding_ends_the_episode_and_the_contacts():
    t, truth = tank(initial_hunger=1.0, turbulence_hz=0.0, bursts_per_hour=0.0, duration_s=(600, 600))
    asking = t.contacts_until(T0 + 60)
    assert t.asking and len(asking) > 10
    t.feed(60.0, T0 + 60)
    assert not t.asking and kinds(truth, "episode_end")[0]["why"] == "fed"
    assert t.contacts_until(T0 + 600) == []
    assert kinds(truth, "fed") == [{"kind": "fed", "t": round(T0 + 60, 4), "tank": "T1", "grams": 60.0}]


def test_unfed_fish_give_up_then_ask_again():
    t, truth = tank(initial_hunger=1.0, turbulence_hz=0.0, bursts_per_hour=0.0, duration_s=(100, 100),
                    rest_s=900)
    t.contacts_until(T0 + 1500)
    ends, starts = kinds(truth, "episode_end"), kinds(truth, "episode_start")
    assert ends[0]["why"] == "gave up" and ends[0]["t"] == pytest.approx(T0 + 100, abs=0.01)
    assert starts[1]["t"] == pytest.approx(T0 + 1000, abs=0.01)


def test_contact_rate_follows_the_episode_rate():
    t, truth = tank(initial_hunger=1.0, turbulence_hz=0.0, bursts_per_hour=0.0, duration_s=(600, 600))
    n = len(t.contacts_until(T0 + 600))
    rate = kinds(truth, "episode_start")[0]["rate_hz"]
    assert abs(n - 600 * rate) < 5 * np.sqrt(600 * rate)


def test_same_seed_same_farm_whatever_the_step():
    a, _ = tank(seed=4, bursts_per_hour=10.0, stuck_per_day=4.0, dead_per_day=4.0)
    b, _ = tank(seed=4, bursts_per_hour=10.0, stuck_per_day=4.0, dead_per_day=4.0)
    coarse = a.contacts_until(T0 + 7200)
    fine = [c for k in range(1, 7201) for c in b.contacts_until(T0 + k)]
    assert coarse == fine and len(coarse) > 500


def test_turbulence_bursts_and_faults_are_logged():
    t, truth = tank(seed=5, initial_hunger=0.0, bursts_per_hour=12.0, turbulence_hz=0.04,
                    stuck_per_day=12.0, dead_per_day=12.0)
    contacts = t.contacts_until(T0 + 86400 / 4)
    assert len(kinds(truth, "burst")) > 40
    faults = {r["fault"] for r in kinds(truth, "sensor_fault")}
    assert faults == {"stuck", "dead"}
    for r in kinds(truth, "sensor_fault"):
        if r["fault"] == "dead":                         # a dead sensor says nothing, fish or not
            a, b = r["t"] + 0.01, r["until"] - 0.01
            assert not [c for c in contacts if c[1] == r["sensor"] and a < c[0] < b]


def test_a_day_asks_for_about_the_ration_in_portions():
    t, truth = tank(seed=6, turbulence_hz=0.0, bursts_per_hour=0.0)
    step = 10.0
    for k in range(int(86400 / step)):                    # the robot serves 60 g 30-40 s after asking
        t.contacts_until(T0 + k * step)
        if t.asking and kinds(truth, "episode_start")[-1]["t"] < T0 + k * step - 30:
            t.feed(60.0, T0 + k * step)
    eaten = sum(r["grams"] for r in kinds(truth, "fed"))
    assert 0.8 * 1080 <= eaten <= 1.2 * 1080             # 2.5 % of 43.2 kg


def test_params_are_strict():
    with pytest.raises(ValidationError):
        SimFishParams(rate=1.0)


def test_fish_fed_by_day_ask_only_within_their_feeding_hours():
    from controller.config import load_config
    cfg = load_config("config/farm.toml")
    t0 = 1_780_016_400.0                                  # local midnight at utc_offset_h = 1
    for hours in ((6.0, 20.0), (22.0, 4.0)):             # a window over midnight too
        tank = SimTank(cfg.tanks[0], SimFishParams(feeding_hours=hours), np.random.default_rng(1), t0=t0,
                       utc_offset_h=1.0)
        starts = []
        for k in range(1, 3 * 24 * 60):
            t = t0 + 60.0 * k
            was = tank.asking
            tank.contacts_until(t)
            if tank.asking and not was:
                starts.append(((t + 3600.0) % 86400.0) / 3600.0)
            if tank.asking and k % 7 == 0:
                tank.feed(200.0, t)                       # served: the episode ends
        lo, hi = hours
        inside = [(lo <= h < hi) if lo < hi else (h >= lo or h < hi) for h in starts]
        assert len(starts) > 10 and all(inside), (hours, starts)


def test_the_next_episode_is_known_ahead_to_the_instant_it_starts():
    """What an elastic clock slows for: the prediction, made between episodes at any step, is the
    episode start the truth log then records (fed by day, given up, rested, fed again)."""
    t, truth = tank(seed=3, initial_hunger=0.2, duration_s=(120, 300), rest_s=600.0, feeding_hours=(6.0, 20.0))
    predicted, now = [], T0
    for step in range(3_000):
        now += 7.0 + (step % 13) * 11.0                  # uneven steps, as a fast clock's ticks are
        before = t.asking
        if not before:
            predicted.append(t.next_episode(now))
        t.contacts_until(now)
        if t.asking and step % 3 == 0:
            t.feed(80.0, now)
    starts = [r["t"] for r in kinds(truth, "episode_start")]
    assert len(starts) > 20
    for s in starts:                                      # each start was foretold just before it
        assert any(p == pytest.approx(s, abs=1e-3) for p in predicted)
    assert t.next_episode(now) >= now or t.asking


def test_a_tank_whose_fish_ask_is_due_now():
    t, _ = tank(initial_hunger=1.0)
    t.contacts_until(T0 + 1.0)
    assert t.asking and t.next_episode(T0 + 1.0) == T0 + 1.0


def test_the_fish_are_heeded_from_their_start_and_each_meal_and_unfed_start_again_after_rest():
    t, truth = tank(initial_hunger=1.0, turbulence_hz=0.0, bursts_per_hour=0.0, duration_s=(300, 300),
                    rest_s=900.0)
    t.contacts_until(T0 + 10.0)
    start = kinds(truth, "episode_start")[0]["t"]
    assert t.heeded_t == start and t.unheeded_until() == pytest.approx(start + 300.0 + 900.0)
    t.feed(5.0, T0 + 20.0)                               # a morsel: still hungry, still asking
    assert t.asking and t.heeded_t == T0 + 20.0
    t.contacts_until(T0 + 5_000.0)                       # nobody feeds them: they give up and rest
    again = [r["t"] for r in kinds(truth, "episode_start")][1]
    assert again >= start + 300.0 + 900.0


def test_fish_fed_a_few_meals_a_day_ask_when_a_meal_s_share_of_the_appetite_is_due():
    """``meals_per_day``: the threshold is that share of a day's appetite (a farm's few large meals),
    and each meal, eaten whole, sates them until the next one is due; the prediction still holds."""
    t, truth = tank(initial_hunger=0.0, turbulence_hz=0.0, bursts_per_hour=0.0, meals_per_day=4.0)
    meal = APPETITE * 86400 / 4                           # 270 g for T1's 43.2 kg at 2.5 % a day
    assert t.threshold_g == pytest.approx(meal)
    predicted = t.next_episode(T0 + 1.0)
    assert predicted == pytest.approx(T0 + 6 * 3600, abs=0.01)
    t.contacts_until(T0 + 6 * 3600 + 30)
    assert t.asking and kinds(truth, "episode_start")[0]["t"] == pytest.approx(predicted, abs=1e-3)
    t.feed(0.5 * meal, T0 + 6 * 3600 + 30)                # half a meal: they ask on
    assert t.asking
    t.feed(0.5 * meal, T0 + 6 * 3600 + 60)
    assert not t.asking
    assert kinds(truth, "episode_end")[0]["why"] == "fed"
    # the minute they asked is part of the next meal's hunger: due six hours after the last start
    assert t.next_episode(T0 + 6 * 3600 + 61) == pytest.approx(T0 + 12 * 3600, abs=0.01)
