"""The demand filter on generated streams of every case of the contact sensor model."""
from __future__ import annotations

import math

import numpy as np
import pytest

from controller.config import validate_section
from controller.demand import (
    Demand,
    DemandFilter,
    DemandParams,
    SensorFault,
    SensorRecovered,
    SlowFishUndetectable,
    threshold,
)
from controller.demand_stats import (
    beat_chain,
    beat_tail,
    beat_threshold,
    caught_within,
    cluster_sizes,
    clustered_threshold,
    rate_for,
)
from controller.errors import BadInput
from devices.sim import contact_streams as cs
from tests import contract_streams as contract

T0 = 1_780_000_000.0
HOUR = 3600.0


def replay(stream, params=None, tanks=None, tick=5.0, until=None):
    """Feed a stream as the controller does: contacts in order, on_time every few seconds."""
    f = DemandFilter(params, tanks)
    events, nxt = [], -math.inf
    for t, tank, sensor in stream.rows():
        if t >= nxt:
            events += f.on_time(t)
            nxt = t + tick
        events += f.on_contact(t, tank, sensor)
    end = until if until is not None else (float(stream.t[-1]) if len(stream) else T0)
    for t in np.arange(nxt, end, tick):
        events += f.on_time(float(t))
    return events, f


def demands(events, tank=None):
    return [e for e in events if isinstance(e, Demand) and (tank is None or e.tank == tank)]


def check_episodes(stream, events):
    """Every episode gets a demand within 60 s of its start; no demand falls outside one."""
    ds = demands(events)
    late = []
    for ep in stream.episodes:
        first = [d.t for d in ds if d.tank == ep.tank and ep.start <= d.t <= ep.end]
        if not first or min(first) - ep.start > 60.0:
            late.append(ep)
    eps = stream.episodes
    outside = [d for d in ds if not any(e.tank == d.tank and e.start <= d.t <= e.end for e in eps)]
    return late, outside


def test_threshold_follows_the_poisson_tail():
    # the contract's worst turbulence needs 18 busy seconds in 60 s; calmer tanks need fewer
    ks = [threshold(b, 60.0, 1e-4, 2) for b in (0.005, 0.01, 0.02, 0.05, 0.1)]
    assert ks == sorted(ks) and ks[3] == 18
    k = ks[3]
    rate = 86400 * 0.05 * math.exp((k - 1) * math.log(3.0) - 3.0 - math.lgamma(k))
    assert rate <= 1e-4 < 86400 * 0.05 * math.exp((k - 2) * math.log(3.0) - 3.0 - math.lgamma(k - 1))


def false_rate(outside, stream_days):
    return len(outside) / stream_days


@pytest.mark.parametrize("turbulence_hz", [0.01, 0.05])
def test_turbulence_and_chatter_alone_stay_within_the_false_demand_budget(turbulence_hz):
    # the simulator's own streams (the independent ones are below): 30 tank-days of turbulence
    # and 6 bursts an hour, at most 0.5 false demands per tank-day, no sensor fault
    rng = np.random.default_rng(11)
    days = [cs.tank_day(rng, "T1", ("a", "b"), T0 + d * 86400, episodes_per_day=1e-9,
                        turbulence_hz=turbulence_hz, bursts_per_hour=6) for d in range(30)]
    stream = cs.merge(*days)
    assert len(stream.bursts) > 3000
    events, _ = replay(stream)
    assert len(demands(events)) <= 0.5 * 30
    assert [e for e in events if isinstance(e, SensorFault)] == []


@pytest.mark.parametrize("pattern", ["poisson", "regular"])
def test_fast_fish_every_episode_within_60s(pattern):
    # 40 tank-days at the contract's worst turbulence, with bursts, fish at 0.7-2 /s: every
    # episode (a chatter burst in an episode's first minute costs evidence, never the deadline)
    rng = np.random.default_rng(7 if pattern == "poisson" else 8)
    days = [cs.tank_day(rng, "T1", ("a", "b"), T0 + d * 86400, rate_hz=(0.7, 2.0), pattern=pattern,
                        turbulence_hz=0.05, bursts_per_hour=4, episodes_per_day=10) for d in range(40)]
    stream = cs.merge(*days)
    assert len(stream.episodes) > 250
    late, outside = check_episodes(stream, replay(stream)[0])
    assert late == []
    assert false_rate(outside, 40) <= 0.5


def test_calm_tank_catches_slower_fish():
    # a calm tank (0.01 /s) lowers its own threshold: every 0.4-0.7 /s episode within 60 s
    rng = np.random.default_rng(5)
    days = [cs.tank_day(rng, "T1", ("a",), T0 + d * 86400, rate_hz=(0.4, 0.7), turbulence_hz=0.01,
                        bursts_per_hour=2, episodes_per_day=10) for d in range(20)]
    stream = cs.merge(*days)
    events, f = replay(stream)
    late, outside = check_episodes(stream, events)
    assert f.score("T1")[1] <= 7 and false_rate(outside, 20) <= 0.5
    assert late == []


def test_several_tanks_are_independent():
    rng = np.random.default_rng(3)
    quiet = cs.turbulence(rng, "T2", ("T2-a",), T0, T0 + 2 * HOUR, 0.05)
    busy = cs.merge(cs.turbulence(rng, "T1", ("T1-a", "T1-b"), T0, T0 + 2 * HOUR, 0.05),
                    cs.fish_demand(rng, "T1", ("T1-a", "T1-b"), T0 + HOUR, 120, 1.0))
    events, _ = replay(cs.merge(quiet, busy))
    assert [d.tank for d in demands(events)] == ["T1"]
    assert T0 + HOUR <= demands(events)[0].t <= T0 + HOUR + 60


def test_sustained_demand_repeats_every_repeat_s_inside_the_episode():
    rng = np.random.default_rng(4)
    ep = cs.fish_demand(rng, "T1", ("a", "b"), T0 + HOUR, 600, 1.0)
    stream = cs.merge(cs.turbulence(rng, "T1", ("a", "b"), T0, T0 + 2 * HOUR, 0.03), ep)
    ds = [d.t for d in demands(replay(stream)[0])]
    assert len(ds) >= 4
    assert all(ep.episodes[0].start <= t <= ep.episodes[0].end for t in ds)
    assert min(np.diff(ds)) >= DemandParams().repeat_s
    assert all(0.3 < d.rate_hz < 1.6 for d in demands(replay(stream)[0]))


def test_demand_time_is_a_contact_of_the_episode():
    rng = np.random.default_rng(9)
    ep = cs.fish_demand(rng, "T1", ("a",), T0 + HOUR, 90, 0.8)
    stream = cs.merge(cs.turbulence(rng, "T1", ("a",), T0, T0 + 2 * HOUR, 0.02), ep)
    (d,) = demands(replay(stream)[0])
    fish = set(stream.t[stream.source == cs.FISH].tolist())
    assert d.t in fish


@pytest.mark.parametrize(("rate", "pattern"), [(5.0, "regular"), (3.0, "regular"), (8.0, "poisson")])
def test_stuck_sensor_is_a_fault_not_a_demand_and_left_out(rate, pattern):
    rng = np.random.default_rng(21)
    sensors = ("a", "b")
    stuck_at, stuck_end = T0 + HOUR, T0 + 2 * HOUR
    fish = cs.fish_demand(rng, "T1", ("b",), T0 + 1.5 * HOUR, 120, 0.8)     # while a is stuck
    stream = cs.merge(cs.turbulence(rng, "T1", sensors, T0, T0 + 3 * HOUR, 0.03), fish,
                      cs.stuck_sensor(rng, "T1", "a", stuck_at, stuck_end, rate, pattern))
    events, f = replay(stream)
    faults = [e for e in events if isinstance(e, SensorFault)]
    assert [(e.sensor, e.kind) for e in faults] == [("a", "stuck")]
    assert stuck_at < faults[0].t < stuck_at + 180
    ds = [d.t for d in demands(events)]
    assert len(ds) == 1 and fish.episodes[0].start <= ds[0] <= fish.episodes[0].start + 60
    rec = [e for e in events if isinstance(e, SensorRecovered)]
    assert [e.sensor for e in rec] == ["a"] and stuck_end < rec[0].t < stuck_end + 180
    assert f.sensor_state("T1", "a") == "healthy"


def test_dead_sensor_is_a_fault_and_recovers_on_its_next_contact():
    rng = np.random.default_rng(22)
    sensors = ("a", "b")
    day = cs.tank_day(rng, "T1", sensors, T0, 0.5, rate_hz=(0.7, 2.0), turbulence_hz=0.05,
                      bursts_per_hour=2, episodes_per_day=24)
    stream = cs.kill_sensor(day, "T1", "b", T0 + 2 * HOUR, T0 + 6 * HOUR)
    events, _ = replay(stream)
    faults = [e for e in events if isinstance(e, SensorFault)]
    assert [(e.sensor, e.kind) for e in faults] == [("b", "dead")]
    assert T0 + 2 * HOUR + DemandParams().dead_after_s <= faults[0].t < T0 + 4 * HOUR
    (rec,) = [e for e in events if isinstance(e, SensorRecovered)]
    assert rec.sensor == "b" and T0 + 6 * HOUR <= rec.t < T0 + 6 * HOUR + 600
    late, outside = check_episodes(stream, events)
    assert late == [] and len(outside) <= 1


def test_configured_sensor_that_never_fires_is_dead():
    rng = np.random.default_rng(23)
    stream = cs.merge(cs.turbulence(rng, "T1", ("a",), T0, T0 + 2 * HOUR, 0.05),
                      cs.fish_demand(rng, "T1", ("a",), T0 + HOUR, 300, 1.0))
    events, _ = replay(stream, tanks={"T1": ["a", "b"]})
    assert [(e.sensor, e.kind) for e in events if isinstance(e, SensorFault)] == [("b", "dead")]


def test_single_sensor_tank_never_reports_dead():
    rng = np.random.default_rng(24)
    stream = cs.turbulence(rng, "T1", ("a",), T0, T0 + 6 * HOUR, 0.001)
    events, _ = replay(stream, until=T0 + 6 * HOUR)
    assert events == []


def test_unknown_tanks_and_sensors_are_ignored_and_counted():
    f = DemandFilter(None, {"T1": ["a"]})
    for i in range(50):
        assert f.on_contact(T0 + i * 0.5, "T9", "x") == ()
        assert f.on_contact(T0 + i * 0.5 + 0.1, "T1", "zz") == ()
    assert f.ignored == 100 and f.unknown == {("T9", "x"), ("T1", "zz")}


def test_params_come_from_the_demand_section_with_one_line_errors():
    p = validate_section(DemandParams, {"repeat_s": 300}, "farm.toml", "demand")
    assert p.repeat_s == 300
    with pytest.raises(BadInput, match=r"farm.toml: demand.repeats: unknown key"):
        validate_section(DemandParams, {"repeats": 3}, "farm.toml", "demand")
    with pytest.raises(BadInput, match=r"farm.toml: demand.window_s: must hold"):
        validate_section(DemandParams, {"window_s": 20, "bin_s": 5}, "farm.toml", "demand")


def test_events_are_frozen_and_common_path_allocates_nothing():
    f = DemandFilter()
    assert f.on_contact(T0, "T1", "a") is f.on_contact(T0 + 0.1, "T1", "a")
    d = Demand("T1", T0, 1.0)
    with pytest.raises(AttributeError):
        d.t = 0.0


# -- beats: regular slow fish -------------------------------------------------------------------

def beat_days(seed, pattern, jitter, fish_sensors, turbulence_hz, rate_hz, days=20):
    """Tank-days of slow regular fish (10 episodes a day) among turbulence and chatter bursts.
    Episodes last 60-115 s: shorter than repeat_s, so every demand is an episode's first."""
    rng = np.random.default_rng(seed)
    parts = []
    for d in range(days):
        a = T0 + d * 86400
        parts += [cs.turbulence(rng, "T1", ("a", "b"), a, a + 86400, turbulence_hz),
                  cs.chatter_bursts(rng, "T1", ("a", "b"), a, a + 86400, 4.0)]
        parts += [cs.fish_demand(rng, "T1", fish_sensors, start, rng.uniform(60, 115), rng.uniform(*rate_hz),
                                 pattern, jitter) for start in cs.episode_starts(rng, a, a + 86400, 10)]
    return cs.merge(*parts)


@pytest.mark.parametrize(("pattern", "jitter", "fish_sensors"), [
    ("regular", 0.1, ("a", "b")),          # a jittered beat spread over the tank's sensors
    ("regular", 0.3, ("a",)),              # a loose beat, all on one sensor
    ("paced", 0.2, ("a", "b")),            # jittered intervals: the phase wanders
])
def test_slow_regular_fish_are_served_within_60s(pattern, jitter, fish_sensors):
    # 0.2-0.3 /s: too slow for the count at 0.02 /s turbulence (it served ~80 % in time), a
    # beat well within the window
    stream = beat_days(31, pattern, jitter, fish_sensors, 0.02, (0.2, 0.3))
    assert len(stream.episodes) > 130
    late, outside = check_episodes(stream, replay(stream)[0])
    assert false_rate(outside, 20) <= 0.5
    assert len(late) <= 0.02 * len(stream.episodes)


def test_regular_fish_at_the_contract_worst_turbulence():
    # 0.05 /s turbulence: a beat at 0.25-0.35 /s is confirmed within the minute
    stream = beat_days(32, "regular", 0.1, ("a", "b"), 0.05, (0.25, 0.35))
    late, outside = check_episodes(stream, replay(stream)[0])
    assert false_rate(outside, 20) <= 0.5
    assert len(late) <= 0.02 * len(stream.episodes)


def test_beat_demand_is_raised_on_a_fish_contact_and_not_repeated_by_the_beat():
    rng = np.random.default_rng(33)
    ep = cs.fish_demand(rng, "T1", ("a", "b"), T0 + HOUR, 600, 0.2, "regular", 0.2)
    stream = cs.merge(cs.turbulence(rng, "T1", ("a", "b"), T0, T0 + 2 * HOUR, 0.02), ep)
    events, f = replay(stream)
    ds = demands(events)
    fish = set(stream.t[stream.source == cs.FISH].tolist())
    assert ds and ds[0].t in fish and ds[0].t - ep.episodes[0].start <= 60
    assert all(ep.episodes[0].start <= d.t <= ep.episodes[0].end for d in ds)
    assert f.score("T1")[0] < f.score("T1")[1]          # the count alone would not have raised it


def test_a_burst_counts_little_whatever_its_size():
    # on a calm tank, one chatter burst of 10 or of 200 contacts adds at most what 10 busy
    # seconds would, and never reaches the threshold on its own
    for n in (10, 30, 200):
        f = DemandFilter()
        rng = np.random.default_rng(n)
        for t in np.sort(rng.uniform(0, 3600, 20)).tolist():       # the tank's own quiet hour
            f.on_contact(T0 + t, "T1", "a")
        f.on_time(T0 + 3600)
        events = []
        for t in np.sort(rng.uniform(3700, 3709.5, n)).tolist():
            events += f.on_contact(T0 + t, "T1", "a")
        f.on_time(T0 + 3715)
        score, k = f.score("T1")
        assert demands(events) == [] and score < min(k, 4), (n, score, k)


def lattice(rng, period, n, jitter, t_end):
    """n contacts of a beat ending near t_end, each moved by up to ±jitter of the period."""
    return (t_end - period * np.arange(n)[::-1] + rng.uniform(-jitter, jitter, n) * period).tolist()


def test_beat_chain_finds_a_beat_among_turbulence_and_across_a_burst():
    rng = np.random.default_rng(35)
    b, d = 0.05, 0.15
    lam = beat_threshold(b, d, 1e-4, 2, 2.0, 12.0)
    args = (d, math.log(2 * d * b), lam, 2.0, 12.0, 60)
    beat = lattice(rng, 4.0, 14, 0.1, 1000.0)
    times = sorted(beat[:-1] + rng.uniform(945, 1000, 3).tolist())       # turbulence in between
    assert beat_chain(times, 0, len(times), beat[-1], *args)
    assert not beat_chain(beat[-9:-1], 0, 8, beat[-1], *args)             # 9 contacts: too few
    # a burst swallowed the beat's 5th contact from the end: the search crosses the lost span
    lost = beat[-5]
    cut = [t for t in beat[:-1] if t != lost]
    assert not beat_chain(cut, 0, len(cut), beat[-1], *args)
    assert beat_chain(cut, 0, len(cut), beat[-1], *args, gaps=[(lost - 2, lost + 3)])
    # the same number of contacts at random is no beat
    poisson = np.sort(rng.uniform(945, 1000, 16)).tolist()
    assert not beat_chain(poisson, 0, 16, 1000.0, *args)


@pytest.mark.parametrize("jitter", [0.15, 0.35])
def test_beat_false_alarm_bound_holds_on_poisson_contacts(jitter):
    # the union bound beat_tail (expected chains with S >= λ per contact) against 20 days of
    # Poisson contacts at 0.05 /s, at levels simulation can reach (the real λ is ~24)
    rng = np.random.default_rng(36)
    b = 0.05
    t = np.sort(rng.uniform(0, 20 * 86400, rng.poisson(b * 20 * 86400))).tolist()
    lo, hits = 0, {8.0: 0, 12.0: 0}
    for k in range(1, len(t)):
        while t[lo] < t[k] - 60:
            lo += 1
        for lam in hits:
            hits[lam] += beat_chain(t, lo, k, t[k], jitter, math.log(2 * jitter * b), lam, 2.0, 12.0, 200)
    for lam, n in hits.items():
        assert n / len(t) <= beat_tail(lam, jitter, b, 2.0, 12.0)
    assert hits[8.0] > 0.03 * beat_tail(8.0, jitter, b, 2.0, 12.0) * len(t)   # and not by far


def test_beat_false_demands_stay_under_their_budget_in_the_filter():
    # the beat's bound in situ (bursts, clumps, the estimated turbulence): with its budget
    # raised to 3 a day and both counts silenced, 20 days of 0.05 /s turbulence and 6 bursts an
    # hour give fewer false demands than budgeted, and some (the bound is not vacuous)
    p = DemandParams(false_alarms_per_day=1e-9, persist_false_alarms_per_day=1e-9,
                     beat_false_alarms_per_day=3.0, repeat_s=1.0)
    rng = np.random.default_rng(37)
    days = 20
    stream = cs.merge(*[cs.tank_day(rng, "T1", ("a", "b"), T0 + d * 86400, episodes_per_day=1e-9,
                                    turbulence_hz=0.05, bursts_per_hour=6) for d in range(days)])
    n = len(demands(replay(stream, p)[0]))
    assert 0 < n <= 3.0 * days


def test_beat_threshold_spends_the_budget():
    lam = [beat_threshold(b, 0.15, 1e-4, 2, 2.0, 12.0) for b in (0.005, 0.02, 0.05)]
    assert lam == sorted(lam)                           # more turbulence, more contacts to test
    q = 1e-4 / (2 * 86400 * 0.05)
    assert beat_tail(lam[2], 0.15, 0.05, 2.0, 12.0) <= q < beat_tail(lam[2] - 0.01, 0.15, 0.05, 2.0, 12.0)


# -- the independent generator (tests/contract_streams.py): the contract's words, not the filter's

def run_farm(farm, params=None):
    """Replay a generated farm as the controller does; (score, filter, events)."""
    f = DemandFilter(params)
    events, nxt = [], -math.inf
    for t, tank, sensor in farm.rows():
        if t >= nxt:
            events += f.on_time(t)
            nxt = t + 5.0
        events += f.on_contact(t, tank, sensor)
    ds = [(e.tank, e.t) for e in events if isinstance(e, Demand)]
    faults = [(e.tank, e.sensor, e.kind, e.t) for e in events if isinstance(e, SensorFault)]
    return contract.score(farm, ds, faults), f, events


def test_every_episode_within_60s():
    # 8 tanks, 8 tank-days: ramps up and down, contacts split over 2-3 sensors, Poisson and
    # paced fish, a chatter burst just before a third of the episodes, waves across tanks. Fish
    # peaking at 0.4-2 /s: EVERY episode gets a demand within 60 s of its first contact
    farm = contract.every(seed=5, days=8)
    assert len(farm.episodes) > 250
    sc, _, _ = run_farm(farm)
    assert [(e.tank, e.first, e.peak_hz) for e in sc.missed] == []
    assert sc.false_per_tank_day <= 0.5 and sc.wrong_faults == 0


# recall within 60 s of the first contact the filter must reach per case, and the ideal bound it
# is measured against (contract.oracle_recall: a detector that knows the background exactly and
# removes every burst, at 0.5 false demands per tank-day). Below ~0.25 /s Poisson fish cannot be
# caught at 0.99 within 60 s by any detector at that false-demand rate: see controller/demand.py.
CASE_GOALS = {
    "band": 0.88, "slow_0.10": 0.40, "slow_0.15": 0.78, "slow_0.20": 0.90, "slow_0.30": 0.98,
    "fast_2.0": 0.99, "paced_0.10": 0.45, "ramped": 0.80, "burst_before": 0.90, "wave": 0.90,
    "split_sensors": 0.90, "busy_0.02": 0.82, "stuck": 0.90, "dead": 0.90,
}


@pytest.mark.parametrize("name", list(contract.CASES))
def test_named_case_scores(name):
    farm = contract.case(name, seed=3, days=4)
    sc, _, _ = run_farm(farm)
    assert sc.episodes >= 100
    assert sc.recall >= CASE_GOALS[name], sc.as_dict()
    # near the ideal bound: within 0.25 at the slow end (where a tank's estimated background,
    # its 5-s bins and its burst rules cost a contact or two), within 0.1 elsewhere
    slack = 0.25 if name in ("slow_0.10", "paced_0.10", "slow_0.15") else 0.1
    assert sc.recall >= contract.oracle_recall(farm) - slack, sc.as_dict()
    assert sc.false_per_tank_day <= 0.75, sc.as_dict()        # 4 tank-days: the long test is below
    assert sc.faults_found == sc.faults and sc.wrong_faults == 0, sc.as_dict()


def test_false_demands_per_tank_day_over_long_streams():
    # 120 tank-days of what tanks show without fish: background 0.002-0.02 /s, chatter bursts
    # 3 /h on each tank, waves 2 /h hitting 3-6 tanks at once
    farm = contract.null_days(seed=6, days=120)
    sc, _, events = run_farm(farm)
    assert len(farm) > 500_000
    assert sc.false_per_tank_day <= 0.5, sc.as_dict()
    assert [e for e in events if isinstance(e, SensorFault)] == []


def test_the_slow_end_bound_is_the_poisson_tail():
    # 60 s after the first contact of a 0.1 /s Poisson episode hold 1 + Poisson(6) contacts
    for k in (3, 5, 8, 9):
        expected = 1.0 - sum(math.exp(-6.0) * 6.0 ** i / math.factorial(i) for i in range(k - 1))
        assert caught_within(0.1, k, 60.0) == pytest.approx(expected, rel=1e-9)
    assert rate_for(0.99, 8, 60.0) == pytest.approx(0.2428, abs=1e-3)
    # and the generator's slow episodes follow it: the oracle at a known background
    farm = contract.case("slow_0.10", seed=4, days=4)
    ks = {t: contract.poisson_threshold(b) for t, b in farm.background_hz.items()}
    analytic = np.mean([caught_within(0.1, ks[e.tank], 60.0) for e in farm.episodes])
    assert abs(contract.oracle_recall(farm) - analytic) < 0.12


def test_a_tank_too_turbulent_for_its_slowest_fish_says_so_once():
    rng = np.random.default_rng(41)
    busy = cs.merge(cs.turbulence(rng, "T1", ("a", "b"), T0, T0 + 86400, 0.05),
                    cs.chatter_bursts(rng, "T1", ("a", "b"), T0, T0 + 86400, 2.0))
    calm = cs.turbulence(rng, "T2", ("a", "b"), T0, T0 + 86400, 0.003)
    events, f = replay(cs.merge(busy, calm), until=T0 + 86400)
    told = [e for e in events if isinstance(e, SlowFishUndetectable)]
    assert [e.tank for e in told] == ["T1"]                   # once, however long it stays so
    assert T0 + DemandParams().learn_s <= told[0].t < T0 + 3 * 3600
    assert "0.1/s" in told[0].note and f.slow_fish("T1") is not None
    assert f.slow_fish("T2") is None


def test_a_burst_that_raised_a_demand_does_not_hold_back_the_fish_after_it():
    # a quiet tank; four turbulence contacts, then a burst whose first contact completes the
    # count (a false demand the filter cannot take back), then fish at 0.5 /s: the burst must
    # not make them wait for the 120 s repeat rule
    rows = [(T0 + 300.0 * i, "T1", "ab"[i % 2]) for i in range(13)]           # an hour, calm
    t1 = T0 + 3900.0
    rows += [(t1 - 50.0, "T1", "b"), (t1 - 40.0, "T1", "a"), (t1 - 30.0, "T1", "b"), (t1 - 20.0, "T1", "a")]
    rows += [(t1 + 0.05 * i, "T1", "b") for i in range(100)]                  # 20 /s for 5 s
    fish = [t1 + 8.0 + 2.0 * i for i in range(40)]
    rows += [(t, "T1", "ab"[i % 2]) for i, t in enumerate(fish)]
    f, events, nxt = DemandFilter(), [], -math.inf
    for t, tank, sensor in sorted(rows):
        if t >= nxt:
            events += f.on_time(t)
            nxt = t + 5.0
        events += f.on_contact(t, tank, sensor)
    assert demands(events)[0].t == t1                   # the burst's first contact raised one
    after = [d.t for d in demands(events) if d.t >= fish[0]]
    assert after and after[0] - fish[0] <= 60.0, [d.t - t1 for d in demands(events)]


def test_a_run_of_contacts_counts_one_busy_second_for_its_first_ten_seconds():
    # bursts collapse to one event on a quiet tank: contacts 0.6 s apart for 6 s (too slow for
    # the chatter and clump rules) count 1 busy second; run_cap = 0 turns it off
    calm = [(T0 + 300.0 * i, "T1", "ab"[i % 2]) for i in range(13)]
    t1 = T0 + 3900.0
    scores = []
    for cap in (1, 0):
        f = DemandFilter(DemandParams(run_cap=cap))
        for t, tank, sensor in calm:
            f.on_time(t)
            f.on_contact(t, tank, sensor)
        f.on_time(t1)
        for i in range(10):
            f.on_contact(t1 + 0.01 + 0.6 * i, "T1", "a")
        scores.append(f.score("T1")[0])
    assert scores[0] <= 1.0 + 1e-9 < scores[1], scores      # uncapped: the spike rule's 2


@pytest.mark.parametrize(("run", "counted"), [(2, 5), (3, 4)])
def test_a_run_of_two_contacts_counts_two_once_it_has_ended(run, counted):
    # slow fish on a quiet tank: single contacts 20 s apart and a run at +40 s 0.3 s apart, then
    # one more at +50 s; a pair is two contacts (slow fish fall within 1 s of each other by
    # chance), a run of three is a burst's: one busy second
    calm = [(T0 + 300.0 * i, "T1", "ab"[i % 2]) for i in range(13)]
    t1 = T0 + 3900.0
    f = DemandFilter()
    for t, tank, sensor in calm:
        f.on_time(t)
        f.on_contact(t, tank, sensor)
    f.on_time(t1)
    for t in (t1 + 0.5, t1 + 20.5, *(t1 + 40.5 + 0.3 * i for i in range(run))):
        f.on_contact(t, "T1", "a")
    before = f.score("T1")[0]
    f.on_contact(t1 + 50.5, "T1", "b")                 # the run has ended
    assert (before, f.score("T1")[0]) == (3, counted)


@pytest.mark.parametrize("rate, least", [(0.3, 0.9), (0.5, 1.0), (1.0, 1.0)])
def test_an_episode_in_a_fresh_filter_s_first_minutes_is_caught_as_at_the_contract_s_bound(rate, least):
    """A tank's first contacts are an episode (a log that starts with one, a controller restarted
    while fish ask): the filter knows only its prior, the contract's turbulence bound (0.05 /s, k 13
    busy seconds: ideal recall 0.99 at 0.3 /s). Its lower confidence bound had put b at 4x that (k ~26)
    and missed every episode below ~0.5 /s there."""
    caught = 0
    for seed in range(30):
        stream = cs.fish_demand(np.random.default_rng(1000 + seed), "T1", ("a", "b"), T0, 300.0, rate)
        late, outside = check_episodes(stream, replay(stream, until=T0 + 300.0)[0])
        caught += not late
        assert outside == []
    assert caught >= least * 30, caught


def test_times_before_zero_are_times_like_any_other():
    """DESIGN: t_s may start anywhere. The same stream shifted by whole hours below zero raises the
    same demands at the same offsets (a second's slot was int(t), so no negative second counted)."""
    rng = np.random.default_rng(12)
    base = cs.merge(cs.turbulence(rng, "T1", ("a", "b"), T0, T0 + 2 * HOUR, 0.02),
                    cs.fish_demand(rng, "T1", ("a", "b"), T0 + HOUR, 300, 0.6))
    want = [round(d.t - T0, 6) for d in demands(replay(base, until=T0 + 2 * HOUR)[0])]
    assert want and any(HOUR <= t <= HOUR + 60 for t in want)
    for shift in (-T0 - 10 * HOUR, -T0 - HOUR, -2 * T0):
        moved = cs.Stream(base.t + shift, base.tank, base.sensor, base.source)
        got = [round(d.t - T0 - shift, 6) for d in demands(replay(moved, until=T0 + shift + 2 * HOUR)[0])]
        assert got == pytest.approx(want, abs=1e-6), shift


# -- slow fish that persist, and sensors stuck fast (an outside tester's streams, 2026-12-05) -------

def _poisson_rows(rng, t0, t1, rate_hz, sensors):
    """Contacts of a Poisson process on the given sensors, straight from the contract's words."""
    t = np.sort(rng.uniform(t0, t1, rng.poisson(rate_hz * (t1 - t0))))
    return [(float(x), sensors[int(rng.integers(len(sensors)))]) for x in t]


def _replay_rows(rows, tank="T1"):
    f = DemandFilter()
    events, nxt = [], -math.inf
    for t, sensor in sorted(rows):
        if t >= nxt:
            events += f.on_time(t)
            nxt = t + 5.0
        events += f.on_contact(t, tank, sensor)
    return events


@pytest.mark.parametrize("period_s", [10.0, 8.0, 6.0])
def test_a_steady_slow_pace_from_a_tank_s_first_contact_is_raised_while_it_lasts(period_s):
    """Fish at 0.1-0.17 /s bumping at a steady pace for 10 minutes, from the first contact a filter
    sees (a controller just started): the count's prior (the contract's 0.05 /s) is far above them,
    and a beat was looked for over the last minute only, where a 10 s pace cannot clear it: such
    episodes were never raised. While the prior holds, the beat is looked for over 180 s."""
    for seed in range(3):
        rng = np.random.default_rng(seed)
        start = 43_200.0 + rng.uniform(0, 1000)
        rows = [(start + i * period_s + rng.uniform(-0.05, 0.05) * period_s, "ab"[i % 2])
                for i in range(int(600 / period_s))]
        ds = [d.t - start for d in demands(_replay_rows(rows))]
        assert ds and 0 <= ds[0] <= 120.0 and max(ds) <= 600.0, (seed, ds)


def test_slow_poisson_fish_that_persist_are_raised_before_they_stop():
    """Poisson fish at 0.1 /s for 10 minutes on a tank at 0.04 /s of turbulence: the minute's count
    catches some; the persistence count (5 minutes, its own small budget) the rest while they ask."""
    raised, outside = 0, []
    for seed in range(20):
        rng = np.random.default_rng(500 + seed)
        start = T0 + HOUR
        rows = (_poisson_rows(rng, T0, start + 900, 0.04, ("a", "b"))
                + _poisson_rows(rng, start, start + 600, 0.1, ("a", "b")))
        ds = [d.t - start for d in demands(_replay_rows(rows))]
        raised += any(0 <= d <= 600 for d in ds)
        outside += [d for d in ds if not 0 <= d <= 600 + contract.AFTERGLOW_S]
    assert raised >= 18 and outside == [], (raised, outside)


def test_a_sensor_stuck_fast_counts_nothing_once_it_has_been_fast_longer_than_any_burst():
    """A sensor stuck at 3 /s with 5 % jitter (some of its bins just under chatter's 15) raised two or
    three demands in the 90 s before it was judged stuck. Fast for 15 s (longer than any burst),
    its contacts count nothing until it slows."""
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        onset = T0 + HOUR
        rows = _poisson_rows(rng, T0, onset + 300, 0.002, ("a", "b"))
        rows += [(onset + (i + rng.uniform(-0.05, 0.05)) / 3.0, "a") for i in range(900)]
        events = _replay_rows(rows)
        assert [d.t for d in demands(events) if d.t > onset + 20] == [], seed
        assert [(e.sensor, e.kind) for e in events if isinstance(e, SensorFault)] == [("a", "stuck")]


# --- turbulence in clusters: sparse random contacts that come as a wave's few hits ---

def test_the_clustered_threshold_is_the_poisson_one_for_single_contacts_and_rises_with_clusters():
    for b in (0.003, 0.01, 0.02, 0.05, 0.2):
        for window, budget in ((60.0, 1.5), (300.0, 0.1)):
            k_min = max(4, math.ceil(b * window) + 1)
            ks = [clustered_threshold(b, window, budget, k_min, single) for single in (1.0, 0.85, 0.55, 0.25, 0.0)]
            assert ks[0] == threshold(b, window, budget, k_min) and ks == sorted(ks), (b, window, ks)
            assert ks[-1] > ks[0]


@pytest.mark.parametrize("b, single", [(0.01, 0.4), (0.02, 0.0), (0.03, 0.7)])
def test_the_clustered_threshold_keeps_its_budget_on_clusters_of_the_model(b, single):
    """Simulated: clusters at b, each of the model's sizes, a busy second 1.5 s apart; the sliding
    60 s count crosses k (the threshold) at most at the budget's rate (and k - 1 well over it)."""
    rng = np.random.default_rng(int(b * 1000) + int(single * 10))
    days, budget = 200.0, 1.5
    starts = np.sort(rng.uniform(0, days * 86400, rng.poisson(b * days * 86400)))
    pmf = np.array(cluster_sizes(single)[1:])
    sizes = rng.choice(np.arange(1, len(pmf) + 1), len(starts), p=pmf / pmf.sum())
    t = np.repeat(starts, sizes) + 1.5 * (np.arange(sizes.sum()) - np.repeat(np.cumsum(sizes) - sizes, sizes))
    t.sort()
    after = np.arange(1, len(t) + 1) - np.searchsorted(t, t - 60.0, side="right")   # the count with each contact
    k = clustered_threshold(b, 60.0, budget, 4, single)

    def crossings(level: int) -> int:        # each contact raises the count by one: it reaches level from below
        return int(np.sum(after == level))
    assert crossings(k) / days <= budget
    assert crossings(k - 1) / days > budget


def _clustered(seed, days, hits_hz, hits, gap_s, episodes=0, peak=(0.7, 2.0)):
    b = contract.Builder(seed)
    b.clustered_background("T1", ("a", "b"), 0.0, days * 86400, hits_hz, hits, gap_s)
    for start in np.arange(7200.0, days * 86400 - 900, 86400 / max(episodes, 1e-9))[:int(episodes * days)]:
        b.episode("T1", ("a", "b"), start + b.rng.uniform(0, 1800), b.rng.uniform(*peak), b.rng.uniform(60, 540),
                  b.rng.uniform(0, 30))
    return b.build(days)


@pytest.mark.parametrize("hits_hz, hits, gap_s", [
    (0.015, (1, 3), (1.2, 2.0)), (0.02, (2, 2), (1.5, 2.5)), (0.015, (1, 3), (2.5, 3.5)), (0.02, (2, 2), (4.0, 5.0))])
def test_turbulence_in_small_clusters_stays_within_the_false_demand_budget(hits_hz, hits, gap_s):
    """Wave hits touching a sensor 1-3 times, 1-5 s apart, 0.03-0.04 contacts/s in all: the count's
    threshold, set for Poisson contacts at the hits' rate, raised 72-97 false demands a day (outside
    tester); the beat took the hits' even spacing for a fish's pace."""
    farm = _clustered(3, 10.0, hits_hz, hits, gap_s)
    assert 0.025 < len(farm) / (10 * 86400) < 0.05
    events, f = replay(farm, params=None, until=10 * 86400)
    assert len(demands(events)) <= 1.5 * 10, len(demands(events))
    assert f.score("T1")[1] > threshold(hits_hz, 60.0, DemandParams().false_alarms_per_day, 4)


def test_a_tank_of_clustered_turbulence_still_serves_its_fish_within_60s():
    farm = _clustered(5, 10.0, 0.015, (1, 3), (1.2, 3.0), episodes=6)
    events, _ = replay(farm, until=10 * 86400)
    late, outside = check_episodes(farm, events)
    assert len(farm.episodes) >= 50 and late == [] and len(outside) <= 1.5 * 10


@pytest.mark.parametrize("turbulence_hz", [0.003, 0.02, 0.05])
def test_poisson_turbulence_and_bursts_keep_the_poisson_thresholds(turbulence_hz):
    """Clustering is read from the shares of empty and single spans: Poisson contacts with chatter
    bursts must not be taken for clusters (on a calm tank the share is a few spans' worth)."""
    rng = np.random.default_rng(17)
    stream = cs.merge(cs.turbulence(rng, "T1", ("a", "b"), T0, T0 + 2 * 86400, turbulence_hz),
                      cs.chatter_bursts(rng, "T1", ("a", "b"), T0, T0 + 2 * 86400, 3.0))
    f = DemandFilter()
    ks = []
    nxt = -math.inf
    for t, tank, sensor in stream.rows():
        if t >= nxt:
            f.on_time(t)
            nxt = t + 60.0
            if t > T0 + 3 * 3600:
                ks.append(f._clustering(f._tanks["T1"]))
        f.on_contact(t, tank, sensor)
    assert np.mean(np.array(ks) == 0) >= 0.95, np.bincount(ks)


@pytest.mark.parametrize("hz", [1.0, 1.5, 2.0, 2.5])
def test_a_sensor_at_a_fixed_rate_longer_than_any_episode_is_stuck_whatever_its_rate(hz):
    """Under the fast test's 3 /s, a sensor stuck at a fixed 1-2.5 /s for an hour was fed every two
    minutes all hour, never flagged (an outside tester). Firing in every bin for longer than the
    contract's longest episode (10 min, and its ramps), it is stuck; quiet for recover_s, it is back."""
    b = contract.Builder(int(hz * 10))
    b.background("T1", ("a", "b"), 0.0, 6 * 3600.0, 0.02)
    b.stuck("T1", "a", 3600.0, 7200.0, hz)
    farm = b.build(0.25)
    events, f = replay(farm, until=6 * 3600.0)
    stuck = [e for e in events if isinstance(e, SensorFault) and e.kind == "stuck"]
    assert [(e.sensor, 3600.0 + 600.0 < e.t <= 3600.0 + 960.0) for e in stuck] == [("a", True)], stuck
    assert len([d for d in demands(events) if 3600.0 <= d.t <= 7200.0]) <= 8          # not 31
    assert [e.sensor for e in events if isinstance(e, SensorRecovered)] == ["a"]
    assert f.sensor_state("T1", "a") == "healthy"


def test_fish_asking_ten_minutes_on_one_sensor_are_no_stuck_sensor():
    b = contract.Builder(8)
    b.background("T1", ("a", "b"), 0.0, 86400.0, 0.01)
    for start in (3600.0, 20000.0, 50000.0):
        b.episode("T1", ("a",), start, 2.0, 600.0, 0.0)
    farm = b.build(1.0)
    events, _ = replay(farm, until=86400.0)
    assert [e for e in events if isinstance(e, SensorFault) and e.kind == "stuck"] == []
    late, _ = check_episodes(farm, events)
    assert late == []


def test_fish_asking_on_one_sensor_do_not_make_the_other_dead():
    """Fish on one sensor of two for minutes: the quiet one was reported dead 114 times in 286
    episodes (an outside tester); 76 in 710 episodes of five such streams, 7 now. The bins of a
    sensor busy for minutes are no evidence against the others."""
    b = contract.Builder(9)
    b.background("T1", ("a", "b"), 0.0, 4 * 86400.0, 0.01)
    for start in np.arange(3600.0, 4 * 86400.0 - 1200.0, 2400.0):
        b.episode("T1", ("a",), start, b.rng.uniform(0.3, 2.0), b.rng.uniform(300.0, 600.0), 0.0)
    farm = b.build(4.0)
    events, _ = replay(farm, until=4 * 86400.0)
    assert len(farm.episodes) > 100
    faults = [e for e in events if isinstance(e, SensorFault)]
    assert {e.kind for e in faults} <= {"dead"} and len(faults) <= 0.02 * len(farm.episodes), faults
    late, _ = check_episodes(farm, events)
    assert len(late) <= 0.02 * len(farm.episodes)
