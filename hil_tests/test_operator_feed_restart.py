"""An operator's feed accepted, then the controller stopped (a clean SIGTERM, then, for a second
feed, SIGKILL) before the robot served it: each restart serves it, once, and the same request id
sent again is a repeat with nothing more fed. Before, the accepted feed lived in memory only: it
was lost on any stop, and the resend under its id was answered "ok, repeat" of a feed never given."""
import signal
import time

import pytest

from hil_tests.farm import HilFarm


def feed(farm: HilFarm, tank: str, request: str) -> dict:
    return farm.tool("override", "feed", f"tank={tank}", "grams=20", f"request={request}", "--operator", "ana",
                     timeout_s=10)[1]


def operator_feeds(farm: HilFarm, tank: str) -> list:
    with farm.ledger() as db:
        return [dict(r) for r in db.execute("SELECT id, tag, phase, grams, demand_id FROM feed "
                                            "WHERE tank = ? AND source = 'operator' ORDER BY seq", (tank,))]


@pytest.mark.hil
def test_an_accepted_operator_feed_outlives_a_stop_and_is_served_once(tmp_path):
    farm = HilFarm(tmp_path, speed=20.0)
    try:
        farm.start_farm()
        for tank, sig in (("T8", signal.SIGTERM), ("T7", signal.SIGKILL)):
            request = f"feed-restart-{tank}"
            first = feed(farm, tank, request)
            assert first["ok"] is True, first
            farm.kill_controller(sig)                  # at once: the robot has not reached the tank
            farm.start_controller()
            farm.wait_controller_up()
            deadline = time.time() + 120
            while not [f for f in operator_feeds(farm, tank) if f["phase"] == "done"]:
                assert time.time() < deadline, farm.log("controller.log")
                time.sleep(0.2)
            again = feed(farm, tank, request)
            assert again == {**first, "repeat": True}, again
            time.sleep(2.0)                            # what a second portion would need to start
            farm.check_alive()
            done = [f for f in operator_feeds(farm, tank) if f["phase"] == "done"]
            assert len(done) == 1 and 10.0 < done[0]["grams"] < 30.0, operator_feeds(farm, tank)   # 20 g asked
            runs = [r for r in farm.truth() if r["kind"] == "auger_run" and r.get("tag") == done[0]["tag"]]
            assert len(runs) == 1, runs                # one physical run, under the row's tag
            with farm.ledger() as db:
                [row] = db.execute("SELECT outcome, source, feed_id FROM demand WHERE id = ?",
                                   (done[0]["demand_id"],)).fetchall()
            assert (row["outcome"], row["source"], row["feed_id"]) == ("served", "operator", done[0]["id"])
    finally:
        farm.stop()
