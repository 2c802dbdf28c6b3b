"""The ledger never frees food it cannot account for: power cuts, lost ledgers, late STARTs,
on the real drivers against the simulated dispenser (see rig.py)."""
import asyncio
from types import SimpleNamespace

import pytest

from controller.feeding.dispensing import COUNTERS, LEDGER
from controller.feeding.robot import Job
from controller.overrides import Overrides
from controller.store import Store
from devices.dispenser.modbus_dispenser import Config as DispenserConfig
from devices.dispenser.modbus_dispenser import ModbusDispenser
from devices.errors import DeviceTimeout
from hil_tests.farm import without_cleaner  # the demo farm's feeder alone
from tests.controller.feeding.rig import rig


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 60))


def intent_now(r, state, **kw):
    return r.store.add_intent(tank="T1", date=r.rations.date(r.clock.now()), t=r.clock.now(), target_g=44.0,
                              run_s=4.0, cycles_before=state.cycles, source="demand", hopper_before=state.hopper_g,
                              device_tags=(state.last_tag, state.run_tag), **kw)


async def restart(r):
    """A new controller process on the same ledger and devices."""
    if r.task is not None:
        r.task.cancel()
        await asyncio.gather(r.task, return_exceptions=True)
    r.robot = r.new_robot()
    r.task = asyncio.create_task(r.robot.run())


async def feed_once_then_die(r):
    """One demand of T1 served, then the controller's task killed."""
    await r.until(lambda: r.robot.state == "idle")
    r.demand("T1")
    await r.until(lambda: not r.robot.pending, what="first run")
    r.task.cancel()
    await asyncio.gather(r.task, return_exceptions=True)


def feed_messages(r, tank="T1"):
    return [p for s, p in r.published.messages if s == f"tank/{tank}/feed"]


def test_a_power_cut_mid_run_leaves_a_suspect_feed_counted_against_the_ration(tmp_path):
    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle")
            r.demand("T1")                                              # a first run: counters move on
            await r.until(lambda: not r.robot.pending, what="first run")
            demand = r.demand("T1")
            await r.until(lambda: r.sim.physics.read().running, what="auger on")
            await r.clock.asleep(1.0)
            r.sim.power_cycle()                                         # site power cut mid-run
            await r.until(lambda: r.store.suspects(), what="suspect feed")
            [cut] = [run for run in r.sim.physics.runs if run.power_cut]
            [suspect] = r.store.suspects()
            assert suspect.tag == cut.tag and cut.physical_g > 5 and suspect.grams is None
            assert "backwards" in suspect.note
            assert LEDGER in r.alarms.active and COUNTERS in r.alarms.active
            ration = r.rations.today("T1", r.clock.now())
            assert ration.committed_g == pytest.approx(ration.fed_g + suspect.target_g)
            # the contract's phases only: the suspect feed is still an intent, flagged
            assert feed_messages(r)[-1] == {**feed_messages(r)[-1], "phase": "intent", "suspect": True}
            # the cut run served its ask (food may have gone in): that ask is not fed again
            assert tuple(r.store.db.execute("SELECT outcome, feed_id FROM demand WHERE id=?", (demand,))
                         .fetchone()) == ("served", suspect.id)
            assert "T1" not in r.robot.pending
            runs = len(r.sim.physics.runs)
            await r.clock.asleep(30.0)
            assert len(r.sim.physics.runs) == runs and r.store.suspects() == [suspect]
            # fish still hungry ask again: a run the counters do see, and the counters alarm
            # clears once they count forward again
            again = r.demand("T1")
            await r.until(lambda: r.store.db.execute("SELECT outcome FROM demand WHERE id=?", (again,))
                          .fetchone()[0] == "served", what="the new ask served")
            assert len(r.sim.physics.runs) == runs + 1
            await r.until(lambda: COUNTERS not in r.alarms.active, what="counters alarm cleared")
            assert LEDGER in r.alarms.active                            # until an operator settles it
            # the operator settles it over the override
            through = Overrides(SimpleNamespace(robot=r.robot, clock=r.clock, store=r.store))
            overrides = SimpleNamespace(settle=lambda payload: through.apply("settle", payload))
            refused = await overrides.settle({"id": suspect.id, "grams": 0})
            assert refused["ok"] is False and "reason" in refused["error"]
            assert (await overrides.settle({"id": "nope", "grams": 3}))["ok"] is False
            assert (await overrides.settle({"id": suspect.id, "grams": -1}))["ok"] is False
            reply = await overrides.settle({"id": suspect.id, "grams": round(cut.physical_g, 1),
                                            "operator": "ana", "reason": "weighed"})
            assert reply == {"ok": True, "phase": "done"}
            assert r.store.suspects() == [] and LEDGER not in r.alarms.active
            assert r.store.feed(suspect.id).grams == pytest.approx(cut.physical_g, abs=0.1)
            assert feed_messages(r)[-1]["phase"] == "done" and feed_messages(r)[-1]["id"] == suspect.id
            assert (await overrides.settle({"id": suspect.id, "grams": 1.0}))["ok"] is False   # once
    run(main())


@pytest.mark.parametrize("when", ["after the run", "mid-run"])
def test_a_restart_after_a_power_cut_never_books_food_as_aborted(tmp_path, when):
    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle")
            if when == "after the run":             # cycles_before > 0: the counters go backwards
                r.demand("T1")
                await r.until(lambda: not r.robot.pending, what="first run")
            demand = r.demand("T1")
            await r.until(lambda: r.sim.physics.read().running, what="auger on")
            r.task.cancel()                         # the controller dies ...
            await asyncio.gather(r.task, return_exceptions=True)
            if when == "after the run":
                await r.until(lambda: not r.sim.physics.read().running, what="run over")
            else:
                await r.clock.asleep(1.0)
            r.sim.power_cycle()                     # ... and the site loses power
            await restart(r)
            await r.until(lambda: r.robot.state == "idle", what="idle after restart")
            last = r.sim.physics.runs[-1]
            [suspect] = r.store.suspects()
            assert suspect.tag == last.tag and last.physical_g > 5
            assert [f for f in r.store.feeds() if f.phase == "aborted"] == []
            assert LEDGER in r.alarms.active
            # its ask was served by it, and is not fed again by the new controller
            assert tuple(r.store.db.execute("SELECT outcome, feed_id FROM demand WHERE id=?", (demand,))
                         .fetchone()) == ("served", suspect.id)
            runs = len(r.sim.physics.runs)
            await r.clock.asleep(30.0)
            assert len(r.sim.physics.runs) == runs and not r.robot.pending
            if when == "after the run":
                assert COUNTERS in r.alarms.active
            else:                                   # 0 -> 0: only the load cell shows food went
                assert "load cell dropped" in suspect.note
    run(main())


def test_a_lost_ledger_does_not_reuse_the_tag_the_dispenser_remembers(tmp_path):
    async def main():
        async with rig(tmp_path) as r:
            await feed_once_then_die(r)
            assert r.sim.physics.last_tag == 1
            r.store.close()
            r.store = Store(tmp_path / "restored.db")         # the ledger is lost: a new one
            r.alarms.store = r.rations.store = r.store
            await restart(r)
            await r.until(lambda: r.robot.state == "idle")
            r.demand("T1")
            await r.until(lambda: not r.robot.pending, what="second run")
            [feed] = r.store.feeds()
            assert feed.tag == 2 and feed.phase == "done"
            # it really ran: not a refused START taken as accepted from the old run's counters
            assert [run.tag for run in r.sim.physics.runs] == [1, 2]
            assert feed.grams == pytest.approx(r.sim.physics.runs[-1].measured_g)
    run(main())


def test_a_start_still_on_the_wire_at_restart_is_settled_as_run(tmp_path):
    """At 2x the margin for a START still on the wire is its 5 farm s (2.5 wall s): the late START
    lands 4.5 farm s inside it whatever the machine's load (at 100x the margin is 0.25 wall s, and
    a loaded machine's connect and write took longer: the run was booked suspect)."""
    async def main():
        async with rig(tmp_path, run=False, speed=2.0) as r:
            state = await r.dispenser.read()
            feed = intent_now(r, state)
            late = ModbusDispenser("late", DispenserConfig(kind="dispenser", driver="modbus", port=r.sim.port),
                                   r.clock)
            await late.open()
            r.robot = r.new_robot()
            r.task = asyncio.create_task(r.robot.run())
            # the dead controller's START lands after the run's planned end
            await r.clock.asleep(feed.t_intent + feed.run_s + 0.5 - r.clock.now())
            try:
                await late.run_auger(feed.run_s, feed.tag)
            finally:
                await late.close()
            await r.until(lambda: r.robot.state == "idle", what="idle after restart")
            [closed] = r.store.feeds()
            assert closed.phase == "done" and len(r.sim.physics.runs) == 1
            assert closed.grams == pytest.approx(r.sim.physics.runs[0].measured_g)
    run(main())


def test_counters_going_backwards_with_nothing_open_are_alarmed(tmp_path):
    async def main():
        async with rig(tmp_path) as r:
            await feed_once_then_die(r)
            r.sim.power_cycle()
            await restart(r)                         # a new process: the ledger remembers the counters
            await r.until(lambda: COUNTERS in r.alarms.active, what="counters alarm")
            assert "cycles 1 -> 0" in r.alarms.active[COUNTERS].text
            assert r.store.suspects() == [] and LEDGER not in r.alarms.active
    run(main())


def test_status_lists_suspect_feeds(tmp_path):
    import tomllib

    import tomli_w

    from controller.alarms import Alarms
    from controller.app import Controller
    from controller.config import load_config
    from controller.feeding.rations import Rations
    from devices.clock import ManualClock

    raw = without_cleaner(tomllib.loads(open("config/farm.toml").read()))
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    c = Controller(load_config(tmp_path / "farm.toml"), ManualClock(1_780_000_000.0))
    c.store = Store(c.cfg.store.path)
    try:
        c.alarms = Alarms(c.store, lambda *a, **k: None, c.clock)
        c.rations = Rations(c.cfg, c.species, c.store)
        assert "suspect" not in c.status()
        f = c.store.add_intent(tank="T1", date=c.rations.date(c.clock.now()), t=c.clock.now(), target_g=44.0,
                               run_s=4.0, cycles_before=3, source="demand")
        c.store.mark_suspect(f.id, "dispenser counters went backwards")
        [s] = c.status()["suspect"]
        assert (s["id"], s["tank"], s["target_g"]) == (f.id, "T1", 44.0) and "backwards" in s["note"]
    finally:
        c.store.close()


def test_the_simulated_dispenser_forgets_its_counters_on_a_power_cycle():
    from devices.clock import ManualClock
    from devices.sim.dispenser_physics import DispenserPhysics, SimDispenserParams
    from devices.sim.truth import TruthLog

    clock, truth = ManualClock(1_780_000_000.0), TruthLog(None)
    dp = DispenserPhysics(SimDispenserParams(seed=1, rate_noise=0, rate_drift=0), clock, truth=truth)
    dp.start_run(2.0, 7)
    clock.advance(3.0)
    dp.start_run(4.0, 8)
    clock.advance(1.0)                        # run 8 half done when the power goes
    before = dp.read()
    assert (before.cycles, before.last_tag, before.run_tag) == (1, 7, 8)
    dp.power_cycle()
    after = dp.read()
    assert (after.cycles, after.last_tag, after.run_tag, after.total_grams, after.running) == (0, 0, 0, 0.0, False)
    assert after.hopper_g == pytest.approx(before.hopper_g, abs=0.1)   # the pellets stay in the hopper
    cut = dp.runs[-1]
    assert cut.power_cut and cut.tag == 8 and cut.physical_g == pytest.approx(11.0, rel=0.01)
    assert [r["kind"] for r in truth.records][-2:] == ["auger_run", "dispenser_power_cycle"]
    assert truth.records[-2]["measured_g"] is None and truth.records[-2]["power_cut"] is True
    dp.start_run(1.0, 7)                      # the tag it forgot is accepted again
    clock.advance(2.0)
    assert dp.read().cycles == 1 and dp.read().last_tag == 7


class LostStartReply:
    """The real dispenser driver whose first START lands on the PLC but whose reply never comes
    back (the driver gave up on a slow PLC: DeviceTimeout after the START ran)."""

    def __init__(self, real):
        self.real, self.lost = real, 0

    def __getattr__(self, name):
        return getattr(self.real, name)

    async def run_auger(self, run_s, tag):
        await self.real.run_auger(run_s, tag)
        if not self.lost:
            self.lost += 1
            raise DeviceTimeout(self.real.name, "no reply within 1.0 s (1 resends)")


@pytest.mark.parametrize("source", ["operator", "demand"])
def test_a_portion_whose_start_reply_was_lost_is_fed_once(tmp_path, source):
    """The START ran, its reply was lost: the fault's recovery settles the intent done from the
    counters, and the job is over. An operator's portion, with no demand to close, was fed again:
    two auger runs, two done rows, for one request."""
    async def main():
        async with rig(tmp_path, wrap=LostStartReply) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            if source == "operator":
                r.robot.on_demand(Job("T1", r.clock.now(), None, "operator", 20.0))
            else:
                r.demand("T1")
            await r.until(lambda: r.dispenser.lost, what="the START's reply lost")
            await r.until(lambda: not r.robot.pending and r.robot.state == "idle" and not r.store.open_intents(),
                          what="the portion settled")
            await r.clock.asleep(60.0)
            feeds = r.store.feeds()
            assert [f.phase for f in feeds] == ["done"] and len(r.sim.physics.runs) == 1
            assert feeds[0].grams == pytest.approx(r.sim.physics.runs[0].measured_g)
    run(main())
