"""A simulated farm day: the real controller process against simulated devices over Zenoh,
Modbus TCP, slcan on a pty and serial on a pty, at high speed."""
import math
import os

import pytest

from controller.demand import DemandParams
from hil_tests.evidence import judge
from hil_tests.farm import HilFarm
from hil_tests.stalls import stalled_s

# Half a farm day in the suite (two minutes of wall time: ~110 fish episodes over eight tanks,
# every part of the day's work); the whole day, twice the evidence, in bench/bench_farm_day.py
# (FISHFARM_HIL_DAY_H=24). Counts the test holds the run to scale with its length.
DAY_H = float(os.environ.get("FISHFARM_HIL_DAY_H", "12"))
DAY_S = DAY_H * 3600.0
PER_DAY = DAY_H / 24.0
# The clock is elastic (devices/elastic_clock.py): SPEED while anything on the farm is busy (fish
# asking, a demand pending, the carriage moving), FAST while the farm is idle (turbulence and
# chatter still come in, stamped in farm time) -- fish ask ~8 % of a day. FISHFARM_HIL_FAST=0
# runs the constant SPEED throughout. At 360x a farm day takes four minutes of wall time. At 1440x
# (a day a minute) one farm minute is 42 ms of wall time, so a Modbus or CAN round trip delayed by a
# busy machine costs farm seconds: the day failed on the 60 s service at load averages of 2.5-9
# (main and the filter alike) and passed 3 of 3 at 360x under the same load.
SPEED = float(os.environ.get("FISHFARM_HIL_SPEED", "360"))
FAST = float(os.environ.get("FISHFARM_HIL_FAST", "7200"))
WARMUP_S = 120.0          # the filter needs its window of evidence before it can judge
LEARN_S = DemandParams().learn_s    # ... and an hour to measure each tank's turbulence


@pytest.mark.hil
def test_a_farm_day_is_fed_on_demand_within_rations(tmp_path):
    """DAY_H farm hours (12 in the suite, 24 in bench/bench_farm_day.py) of the demo farm."""
    # a stuck and a dead sensor every few days per tank (a couple of each over the farm's day),
    # and line noise on the contact hub's serial line
    farm = HilFarm(tmp_path, speed=SPEED, elastic=(SPEED, FAST) if FAST > SPEED else None,
                   overrides={"sim": {"fish": {"stuck_per_day": 0.3, "dead_per_day": 0.3},
                                      "contacts": {"noise_per_s": 5.0}}})
    try:
        farm.start_sim()
        farm.start_controller()
        up = farm.wait_controller_up()
        end = up + DAY_S
        farm.sleep_until_farm(end)
        farm.check_alive()
    finally:
        farm.stop()
    everything = farm.truth()          # (the simulator's truth log, read once)
    truth = [r for r in everything if r["t"] >= up + WARMUP_S or r["kind"] == "auger_run"]
    stalls = farm.stalls()
    with farm.ledger() as db:
        verdict = judge(db, everything, end, since=up + WARMUP_S, stalls=stalls)
        alarms = [dict(r) for r in db.execute("SELECT * FROM alarm WHERE source LIKE 'sensor/%' AND active = 1")]
        raised = [(r["tank"], r["t"]) for r in db.execute("SELECT tank, t FROM demand WHERE source = 'demand'")]
    faults = [r for r in everything if r["kind"] == "sensor_fault" and up < r["t"] < end - 600]
    late, faulty = [], []
    for tank, a, b, rate in _spans(truth, end):
        # the time the machine stood still (hil_tests/stalls.py) is nobody's: it extends the 60 s
        window = 60 + stalled_s(stalls, a, a + 60 + stalled_s(stalls, a, a + 60))
        if any(k == tank and a <= t <= min(b, a + window) for k, t in raised) or b - a < 60:
            continue
        first = min((t - a for k, t in raised if k == tank and a <= t <= b), default=float("inf"))
        before = max((t for k, t in raised if k == tank and t < a), default=-math.inf)
        text = (f"{tank} asked at {a:.1f} ({rate:.3f}/s, {b - a:.0f} s): first demand after {first:.1f} s,"
                f" the one before {a - before:.0f} s earlier")
        # a faulty sensor takes its share of the fish's contacts with it, and in its first hour
        # the filter is still measuring the tank (it starts at the contract's worst turbulence)
        hit = any(f["tank"] == tank and f["t"] - 60 <= b and a <= f["until"] for f in faults)
        (faulty if hit or a < up + LEARN_S else late).append(text)
    report = verdict.summary()
    print(report)
    print(f"machine stalls: {len(stalls)}, {sum(b - a for a, b in stalls) / SPEED:.2f} s of wall; "
          f"{verdict.stalled}")
    assert not verdict.problems, "\n".join([report, *verdict.problems, *verdict.false_demands,
                                             farm.log("controller.log")[-4000:]])
    assert verdict.feeds >= 100 * PER_DAY and verdict.episodes >= 100 * PER_DAY, report
    # demands that come together from tanks across the rail can outrun one robot: such waits are
    # counted, each under 120 s with the robot busy serving others the whole time, and rare
    assert len(verdict.queued) <= max(2, verdict.feeds // 50), "\n".join([report, *verdict.queued])
    # demands outside every episode: within the filter's budget, 0.5 a tank-day
    tanks = {r["tank"] for r in truth if r["kind"] == "episode_start"}
    budget = max(1.0, 0.5 * len(tanks) * PER_DAY)
    assert len(verdict.false_demands) <= budget, "\n".join([report, *verdict.false_demands])
    # the contract: every episode demanded within 60 s of its start, for the fish the sim makes
    # (paced, the whole 0.1-2 /s band, calm tanks; Poisson fish at the slow end are a documented
    # limit, measured in bench/bench_demand.py)
    # with every sensor healthy and the tank measured, 100 %; the rest (above) are held to 180 s
    assert late == [], "\n".join([report, *late])
    # within 180 s, every episode but those a faulty sensor took below the contract's band: fish at
    # 0.143 /s with one of T7's two sensors stuck were 0.07 /s to the filter, and gave up in 105 s
    # (a CI run, 2026-12-06): no demand, by the contract's own floor
    below = _below_the_band(truth, faults, farm.config["tanks"], end)
    missed = sum(d > 180 for d in verdict.detection_s)
    assert missed <= len(below), "\n".join([report, *faulty, f"below the band: {below}"])
    print(f"late while measuring or with a faulty sensor: {faulty}")
    if farm.watch is not None:      # every episode was served at SPEED: none started on the fast clock
        fast = [(r["tank"], r["t"]) for r in truth if r["kind"] == "episode_start" and r["t"] < end - 60
                and farm.watch.ran_fast_at(r["t"])]
        assert fast == [], fast
    rates = [r["rate_hz"] for r in truth if r["kind"] == "episode_start"]
    assert min(rates) <= 0.15 and max(rates) >= 1.2, sorted(rates)
    # a stuck sensor is always caught; any sensor alarm names a sensor that really failed, while it did
    for fault in (f for f in faults if f["fault"] == "stuck"):
        assert any(a["source"] == f"sensor/{fault['sensor']}" and "stuck" in a["text"]
                   and fault["t"] <= a["t"] <= fault["until"] for a in alarms), (fault, alarms)
    # a dead sensor is caught once the tank's other sensor has fired enough to tell (~100 fish
    # contacts while it was dead)
    spans = _spans(truth, end)
    for fault in (f for f in faults if f["fault"] == "dead"):
        heard = sum(max(0.0, min(fault["until"], b) - max(fault["t"], a)) * rate / 2
                    for tank, a, b, rate in spans if tank == fault["tank"])
        if heard >= 100:
            assert any(a["source"] == f"sensor/{fault['sensor']}" and "dead" in a["text"]
                       and fault["t"] <= a["t"] <= fault["until"] + 60 for a in alarms), (fault, alarms)
    for alarm in alarms:
        sensor = alarm["source"].removeprefix("sensor/")
        assert any(f["sensor"] == sensor and f["t"] <= alarm["t"] <= f["until"] + 60 for f in faults), \
            (alarm, faults)
    print(f"{len(faults)} sensor faults, {len(alarms)} sensor alarms")


BAND_FLOOR = 0.1       # contacts/s: the slowest fish demand the contract covers (controller/demand.py)


def _below_the_band(truth: list[dict], faults: list[dict], tanks: list[dict], end_t: float) -> list[str]:
    """Episodes whose contacts, less a faulty sensor's share while it was faulty, fell below the
    contract's band (the fish ask each sensor of their tank alike)."""
    sensors = {t["id"]: len(t["sensors"]) for t in tanks}
    out = []
    for tank, a, b, rate in _spans(truth, end_t):
        hit = {f["sensor"] for f in faults if f["tank"] == tank and f["t"] <= b and a <= f["until"]}
        if hit and rate * (sensors[tank] - len(hit)) / sensors[tank] < BAND_FLOOR:
            out.append(f"{tank} at {a:.1f} ({rate:.3f}/s, {b - a:.0f} s; {sorted(hit)} faulty)")
    return out


def _spans(truth: list[dict], end_t: float) -> list[tuple[str, float, float, float]]:
    """(tank, start, end, rate) of every fish episode."""
    open_, out = {}, []
    for r in sorted((r for r in truth if r["kind"] in ("episode_start", "episode_end")), key=lambda r: r["t"]):
        if r["kind"] == "episode_start":
            open_[r["tank"]] = r
        elif r["tank"] in open_:
            start = open_.pop(r["tank"])
            out.append((r["tank"], start["t"], r["t"], start["rate_hz"]))
    out += [(tank, r["t"], end_t, r["rate_hz"]) for tank, r in open_.items()]
    return out
