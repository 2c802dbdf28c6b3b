"""A paused tank's demands are not served; the others' are; the pause outlives a restart."""
import asyncio

from controller.feeding.robot import Job
from tests.controller.feeding.rig import rig


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 60))


def outcome(r, demand_id):
    return r.store.db.execute("SELECT outcome FROM demand WHERE id = ?", (demand_id,)).fetchone()[0]


def test_a_paused_tank_is_not_served_and_the_others_are(tmp_path):
    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            r.store.pause_tank("T1", r.clock.now(), "ana")          # as the pause override does
            r.robot.pause("T1")
            paused, other = r.demand("T1"), r.demand("T2")
            await r.until(lambda: outcome(r, other) == "served", what="T2 served")
            assert outcome(r, paused) == "paused" and "T1" not in r.robot.pending
            assert {f.tank for f in r.store.feeds()} == {"T2"} and set(r.delivered) == {"T2"}
            r.store.resume_tank("T1")
            r.robot.resume("T1")
            again = r.demand("T1")
            await r.until(lambda: outcome(r, again) == "served", what="T1 served once resumed")
    run(main())


def test_pausing_drops_the_waiting_demand_and_a_restart_stays_paused(tmp_path):
    async def main():
        async with rig(tmp_path, run=False) as r:
            waiting = r.demand("T1")
            assert "T1" in r.robot.pending
            r.store.pause_tank("T1", r.clock.now(), "ana")
            r.robot.pause("T1")
            assert r.robot.pending == {} and outcome(r, waiting) == "paused"
            restarted = r.new_robot()                                # the ledger says T1 is paused
            assert restarted.paused == {"T1"}
            late = r.store.add_demand("T1", r.clock.now(), 0.5)
            restarted.on_demand(Job("T1", r.clock.now(), late))
            assert restarted.pending == {} and outcome(r, late) == "paused"
    run(main())


def test_a_tank_paused_while_the_robot_is_on_its_way_or_reading_the_dispenser_is_not_fed():
    """A pause accepted while the robot was at the tank reading the dispenser's state was followed
    by the intent and 58.7 g: only a portion whose intent is written is "on its way"."""
    import tempfile
    from pathlib import Path

    async def main(tmp_path, when):
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            read = r.robot.dispensing.read

            async def pausing_read():                # the operator's pause lands during this await
                state = await read()
                if when == "reading" and r.robot.state == "dispensing":
                    r.robot.pause("T2")
                return state
            r.robot.dispensing.read = pausing_read
            asked = r.demand("T2")
            if when == "moving":
                await r.until(lambda: r.robot.state == "moving", what="moving")
                r.robot.pause("T2")
            await r.until(lambda: outcome(r, asked) == "paused" and r.robot.state == "idle", 300.0,
                          what="the demand closed paused")
            await asyncio.sleep(0.05)
            return [f.tank for f in r.store.feeds()], dict(r.delivered)
    for when in ("moving", "reading"):
        with tempfile.TemporaryDirectory() as d:
            feeds, delivered = run(main(Path(d), when))
            assert feeds == [] and delivered == {}, when
