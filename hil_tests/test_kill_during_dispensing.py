"""SIGKILL the controller at 20 random instants while it dispenses; restart it each time.
The ledger must still equal what physically left the auger: nothing lost, nothing repeated."""
import random
import sqlite3
import time

import pytest

from hil_tests.evidence import judge
from hil_tests.farm import HilFarm

SPEED = 200.0
KILLS = 20


def wait_for_open_intent(farm: HilFarm, after_seq: int, timeout_s: float = 60.0):
    """Poll the ledger (read-only, beside the controller's WAL writer) for a new open intent: not
    one a previous kill left for the restarted controller to settle."""
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        farm.check_alive()
        try:
            with farm.ledger() as db:
                row = db.execute("SELECT seq, run_s FROM feed WHERE phase = 'intent' AND seq > ?",
                                 (after_seq,)).fetchone()
        except sqlite3.OperationalError:       # the ledger does not exist yet
            row = None
        if row is not None:
            return row
        time.sleep(0.002)
    raise AssertionError(f"no dispense started within {timeout_s} s:\n{farm.log('controller.log')}")


@pytest.mark.hil
def test_sigkill_while_dispensing_neither_loses_nor_repeats(tmp_path):
    rng = random.Random(20)
    farm = HilFarm(tmp_path, speed=SPEED)
    killed_open = 0
    try:
        farm.start_sim()
        farm.start_controller()
        farm.wait_controller_up()
        last_seq = 0
        for _ in range(KILLS):
            feed = wait_for_open_intent(farm, last_seq)
            last_seq = feed["seq"]
            # anywhere from just after the intent's commit to just after the auger stops
            time.sleep(rng.uniform(0.0, 1.2 * feed["run_s"] / SPEED))
            farm.kill_controller()
            with farm.ledger() as db:
                killed_open += db.execute("SELECT COUNT(*) FROM feed WHERE phase = 'intent'").fetchone()[0]
            farm.start_controller()
            farm.wait_controller_up()
        end = farm.farm_now() + 600.0                 # let the last restart settle and serve
        farm.sleep_until_farm(end)
    finally:
        farm.stop()
    with farm.ledger() as db:
        open_left = db.execute("SELECT COUNT(*) FROM feed WHERE phase = 'intent'").fetchone()[0]
        aborted = db.execute("SELECT COUNT(*) FROM feed WHERE phase = 'aborted'").fetchone()[0]
        verdict = judge(db, farm.truth(), end)
    report = (f"{farm.restarts} kills, {killed_open} left an open intent, {aborted} intents never ran; "
              + verdict.summary())
    print(report)
    assert farm.restarts == KILLS
    assert killed_open >= KILLS // 2, report            # most kills really hit a dispense in flight
    assert open_left == 0, report
    ledger_problems = [p for p in verdict.problems if "auger run" in p or "ledger" in p or "load cell" in p
                       or "matches" in p or "fed" in p]
    assert not ledger_problems, report + "\n" + "\n".join(ledger_problems)
    assert abs(verdict.ledger_g - verdict.physical_g) <= 0.1 * max(1, verdict.runs), report
