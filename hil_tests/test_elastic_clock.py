"""The elastic clock on the real processes: an evening's feeding, a night and a morning's, with the
farm clock fast only while nobody needs fine time (devices/elastic_clock.py). The feeding is
judged as the farm day's (hil_tests/evidence.py) and every fish episode must have found the clock
slow when it started; the night must have gone by fast."""
import os
import re

import pytest

from hil_tests.evidence import judge
from hil_tests.farm import HilFarm

SLOW = float(os.environ.get("FISHFARM_HIL_SPEED", "360"))     # the farm day's speed: proven under load
FAST = 8640.0                                                   # a farm day in 10 wall s
START = 1_780_066_800.0        # 2026-05-29 16:00 local (utc_offset_h = 1): four hours before the fish stop
SPAN_S = 16 * 3600.0           # ... to 08:00 the next morning (the fish feed 06:00-20:00)
WARMUP_S = 120.0
QUEUED = re.compile(r"started ([\d.]+) s after its demand \(([1-9]\d*) other feeds between\)")
# a feed ahead in the queue holds the robot at most this long: the rail's length at 1 m/s there and
# back, a portion through the auger, the gate and the load cell settling
PER_FEED_S = 45.0


@pytest.mark.hil
def test_the_farm_runs_fast_through_the_night_and_slow_for_every_episode(tmp_path):
    farm = HilFarm(tmp_path, speed=SLOW, farm_start=START, elastic=(SLOW, FAST),
                   overrides={"sim": {"fish": {"feeding_hours": [6.0, 20.0]}}})
    try:
        farm.start_sim()
        farm.start_controller()
        up = farm.wait_controller_up()
        wall0 = farm.watch.samples[-1][0]
        farm.sleep_until_farm(START + SPAN_S)
        end = farm.farm_now()
        farm.check_alive()
    finally:
        farm.stop()
    wall = farm.watch.samples[-1][0] - wall0
    truth = [r for r in farm.truth() if r["t"] >= up + WARMUP_S or r["kind"] == "auger_run"]
    starts = [r for r in truth if r["kind"] == "episode_start" and r["t"] < end - 60]
    with farm.ledger() as db:
        verdict = judge(db, truth, end, since=up + WARMUP_S, stalls=farm.stalls())
    report = f"{verdict.summary()}\nwall {wall:.1f} s for {(end - up) / 3600:.1f} farm h\n{farm.watch.summary()}"
    print(report)
    assert len(starts) >= 40, report                         # both feeding spells were lived through
    fast_at_start = [f"{r['tank']} at {r['t']:.0f}" for r in starts if farm.watch.speed_after(r["t"]) >= FAST]
    assert fast_at_start == [], report
    # the fish feed by day: at 06:00 every tank asks at once after the night, and the robot serves
    # them one by one (8 tanks, ~15-35 s a feed): such a wait is the queue's when it is no longer
    # than the feeds ahead of it take
    problems = [p for p in verdict.problems
                if not ((m := QUEUED.search(p)) and float(m[1]) <= PER_FEED_S * (int(m[2]) + 1))]
    assert problems == [], "\n".join([report, *verdict.problems, farm.log("controller.log")[-4000:]])
    assert verdict.detected_within(180) == 1.0, report
    # the ten fishless hours took a few wall seconds: the whole run well under a slow clock's half
    assert wall < 0.5 * (end - up) / SLOW, report
