"""A simulated farm day: the real controller process against simulated devices over Zenoh,
Modbus TCP, slcan on a pty and serial on a pty, at high speed."""
import os

import pytest

from hil_tests.evidence import judge
from hil_tests.farm import HilFarm

DAY_S = 86_400.0
SPEED = float(os.environ.get("FISHFARM_HIL_SPEED", "1440"))   # a farm day in a minute of wall time
WARMUP_S = 120.0          # the filter needs its window of evidence before it can judge


@pytest.mark.hil
def test_a_farm_day_is_fed_on_demand_within_rations(tmp_path):
    farm = HilFarm(tmp_path, speed=SPEED)
    try:
        farm.start_sim()
        farm.start_controller()
        up = farm.wait_controller_up()
        end = up + DAY_S
        farm.sleep_until_farm(end)
        farm.check_alive()
    finally:
        farm.stop()
    truth = [r for r in farm.truth() if r["t"] >= up + WARMUP_S or r["kind"] == "auger_run"]
    verdict = judge(farm.ledger(), truth, end)
    report = verdict.summary()
    print(report)
    assert not verdict.problems, "\n".join([report, *verdict.problems, farm.log("controller.log")])
    assert verdict.feeds >= 100 and verdict.episodes >= 100, report
    # the filter's contract (a demand within 60 s of an episode's start) is a statistical one at
    # the slow end of the fish band; every episode is found, nearly all within the minute
    assert verdict.detected_within(60) >= 0.9 and verdict.detected_within(180) == 1.0, report
