"""The e-stop is the devices' latches plus a stop token, never a cancellation.

An e-stop is tripped at each awaited step of a dispense, the instant the device's reply has come
back (in the same loop turn, before the robot's code resumes): with the action cancelled in that
same turn, and with no cancellation at all (the worst case: a cancel swallowed, or a loop that
has not heard yet). In every case the auger never starts after the e-stop — checked at the
simulated PLC, over real Modbus — and the ledger still matches what left the hopper.
"""
from __future__ import annotations

import asyncio
import time

import pytest

from controller.feeding.estop import EstopLane
from controller.feeding.robot import Job
from tests.controller.feeding.rig import rig


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 60))


class Tripwire:
    """The real dispenser driver, with ``hook(call, robot)`` run the moment a call's reply is back."""

    def __init__(self, real):
        self.real = real
        self.hook = None

    def __getattr__(self, name):
        return getattr(self.real, name)

    async def read(self):
        state = await self.real.read()
        if self.hook is not None:
            self.hook("read")
        return state

    async def run_auger(self, run_s, tag):
        await self.real.run_auger(run_s, tag)
        if self.hook is not None:
            self.hook("run_auger")


STEPS = ["before_intent", "between_intent_and_start", "while_running", "reading_counters"]


@pytest.mark.parametrize("cancel", ["cancelled_same_turn", "never_cancelled"])
@pytest.mark.parametrize("step", STEPS)
def test_estop_at_each_step_of_a_dispense_never_lets_the_auger_start_after_it(tmp_path, step, cancel):
    async def main():
        async with rig(tmp_path, wrap=Tripwire) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            tripped = []

            def trip():
                if tripped:
                    return
                tripped.append(r.sim.physics.clock.now())
                r.robot.lane.trip("test")                      # what the Zenoh thread does
                if cancel == "cancelled_same_turn":
                    asyncio.current_task().cancel()            # lands with the reply, same turn
                    asyncio.get_running_loop().create_task(r.robot.emergency_stop("test"))

            def on_call(call):
                if r.robot.state != "dispensing":
                    return
                intent = bool(r.store.open_intents())
                if (step == "before_intent" and call == "read" and not intent
                        or step == "while_running" and call == "run_auger"
                        or step == "reading_counters" and call == "read" and intent):
                    trip()

            def on_publish(suffix, payload):
                if step == "between_intent_and_start" and suffix.endswith("/feed") and payload["phase"] == "intent":
                    trip()

            r.dispenser.hook = on_call
            r.published.hook = on_publish
            runs_before = len(r.sim.physics.runs)
            r.demand("T2")
            await r.until(lambda: r.robot.state == "estop", what="estop")
            await r.until(lambda: r.robot.lane._confirmed.done(), what="latches confirmed")
            assert tripped
            latched_t = r.sim.physics.estops[0][0]
            await r.clock.asleep(10.0)                          # long past any portion's run time
            physics = r.sim.physics
            assert physics.estop_latched and not physics.read().running and r.motor.state == "estop"
            # the auger never started after the e-stop: every run began before the latch
            assert all(run.t_start <= latched_t for run in physics.runs)
            if step in ("before_intent", "between_intent_and_start"):
                assert len(physics.runs) == runs_before and r.delivered.get("T2", 0.0) == 0.0
            else:
                assert len(physics.runs) == runs_before + 1 and physics.runs[-1].t_end <= latched_t + 1e-9
            # released: the latches are reset, the open intent settled from the counters, and the
            # ledger matches what left the hopper, run by run
            assert r.robot.operator_reset() is None
            await r.until(lambda: r.robot.state == "idle", farm_s=200, what="back to idle")
            assert not physics.estop_latched and r.store.open_intents() == []
            fed = sum(f.grams or 0.0 for f in r.store.feeds() if f.phase == "done")
            assert fed == pytest.approx(r.delivered.get("T2", 0.0), abs=0.1 + 1e-9)
            served = r.demand("T1")                              # and it serves again
            await r.until(lambda: r.store.db.execute("SELECT outcome FROM demand WHERE id=?", (served,))
                          .fetchone()[0] == "served", what="served after the reset")
    run(main())


def test_a_start_sent_after_the_latch_is_refused_by_the_device(tmp_path):
    """Past every check (a bug, or a START already queued): the PLC itself refuses it."""
    async def main():
        async with rig(tmp_path, run=False) as r:
            await asyncio.to_thread(r.dispenser.trip_estop)
            with pytest.raises(Exception, match="e-stop"):
                await r.dispenser.run_auger(5.0, tag=77)
            assert r.sim.physics.runs == [] and not r.sim.physics.read().running
    run(main())


def test_estop_while_the_loop_is_blocked_latches_both_devices(tmp_path):
    """The lane needs no loop: with the robot's loop blocked, both latches are set and confirmed.
    (The simulated devices run on a thread of their own here.)"""
    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            # serve the simulated PLC from its own thread, so a blocked loop does not silence it
            await r.sim.stop()
            r.sim.start_thread()
            try:
                dispenser = type(r.dispenser)("dispenser", r.dispenser.config.model_copy(
                    update={"port": r.sim.port}), r.clock)
                await dispenser.open()
                lane = EstopLane(_DeafRail(), dispenser)
                done = lane.trip("blocked loop")
                started = time.monotonic()
                assert done.result(timeout=2.0) is True                # the loop never ran meanwhile
                assert time.monotonic() - started < 1.0 and r.sim.physics.estop_latched
                lane.close()
                await dispenser.close()
            finally:
                r.sim.stop_thread()
    run(main())


class _DeafRail:
    """A drive that confirms at once (the CAN side is tested in tests/devices/test_rail_can.py)."""

    def trip_estop(self):
        self.sent = time.monotonic()

    def estop_seen_since(self, t):
        return True


class _Unreachable:
    name = "dispenser"

    def __init__(self):
        self.calls = 0

    def trip_estop(self):
        from devices.errors import LinkDown
        self.calls += 1
        raise LinkDown("dispenser", "cannot connect")


def test_unconfirmed_latch_is_reported_retried_and_release_stops_the_sends():
    reports = []
    rail, dispenser = _DeafRail(), _Unreachable()
    lane = EstopLane(rail, dispenser, confirm_within_s=0.05, retry_s=0.005)
    lane.listen(lambda device, why: reports.append((device, why)))
    done = lane.trip("test")
    assert lane.tripped
    deadline = time.monotonic() + 2.0
    while not reports and time.monotonic() < deadline:
        time.sleep(0.005)
    assert reports == [("dispenser", "cannot connect")] and not done.done()
    calls = dispenser.calls
    # it keeps trying (backing off: by the time a loaded machine delivers the report the next
    # try may be a few hundred ms away, so wait for it rather than for a fixed time)
    deadline = time.monotonic() + 5.0
    while dispenser.calls == calls and time.monotonic() < deadline:
        time.sleep(0.005)
    assert dispenser.calls > calls
    # a reset asks whether the stop is still being confirmed: yes within the window it gives, no after
    assert lane.confirming(60.0) and not lane.confirming(0.0)
    lane.release()
    assert not lane.tripped and not lane.confirming(60.0)
    calls = dispenser.calls
    time.sleep(0.1)
    assert dispenser.calls == calls                             # and stops once released
    lane.close()


class _Recording:
    """A drive and a dispenser that latch at once and note which thread reached them."""

    def __init__(self):
        self.threads = []

    def trip_estop(self):
        import threading
        self.threads.append(threading.current_thread())
        from devices.dispenser import DispenserState
        return DispenserState(0, False, False, False, 0, 0, 0, 0, 0.1, estop=True)

    def estop_seen_since(self, t):
        return bool(self.threads)


def test_trip_from_a_thread_without_a_loop_reaches_both_devices_before_it_returns():
    """The Zenoh thread's path: the first ESTOPs leave from the caller, no hop to the lane's thread."""
    import threading
    rail, dispenser = _Recording(), _Recording()
    lane = EstopLane(rail, dispenser)
    done = []
    caller = threading.Thread(target=lambda: done.append((lane.trip("zenoh"), list(rail.threads),
                                                          list(dispenser.threads))))
    caller.start()
    caller.join(5)
    confirmed, drive_threads, dispenser_threads = done[0]
    assert drive_threads == [caller] and dispenser_threads == [caller]
    assert confirmed.result(timeout=2.0) is True
    lane.close()


def test_the_estop_alarm_names_the_operator_whose_override_the_loop_heard_of_first(tmp_path):
    """An override's e-stop trips on the Zenoh thread under a provisional reason before its payload
    is read; a robot loop that noticed the trip first raised the alarm with that reason, and the
    operator's own never reached it ('emergency stop: operator e-stop' though the audit said H)."""
    from controller.feeding.estop import PROVISIONAL

    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            r.robot.lane.trip(PROVISIONAL)                        # the Zenoh thread, first
            await r.until(lambda: r.robot.state == "estop", what="the loop heard of it")
            first = r.alarms.active[("estop", "latched")].text
            await r.robot.emergency_stop("operator H: the auger jammed")
            await r.clock.asleep(5.0)                             # the latches' confirmations reported
            alarm = r.alarms.active[("estop", "latched")]
            return first, alarm.text, r.robot.lane.reason, alarm.count, alarm.repeats
    first, then, reason, count, repeats = run(main())
    assert first.startswith(f"emergency stop: {PROVISIONAL}")
    assert then.startswith("emergency stop: operator H: the auger jammed") and reason == "operator H: the auger jammed"
    # one e-stop, raised once: its text refined is no raise (an outside tester: one e-stop, count 2)
    assert count == 1 and repeats == 0, (count, repeats)


def test_a_second_estop_does_not_rename_the_first():
    lane = EstopLane(_DeafRail(), _DeafRail())
    lane.trip("modbus e-stop by scada")
    lane.trip("operator H")
    assert lane.reason == "modbus e-stop by scada"
    lane.close()


def test_a_drive_estopped_at_its_own_panel_mid_dispense_stops_the_auger(tmp_path):
    """The auger ran its whole portion: the robot heard of the drive's e-stop at its next move, and
    took it for a fault first."""
    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            r.demand("T2")
            await r.until(lambda: r.sim.physics.read().running, what="auger on")
            pressed = r.clock.now()
            r.motor.press_estop()
            await r.until(lambda: r.sim.physics.estop_latched, farm_s=30.0, what="the dispenser latched")
            assert r.clock.now() - pressed < 0.5 * 100       # within half a wall second at 100x
            run_ = r.sim.physics.runs[-1]
            assert run_.t_end <= r.sim.physics.estops[0][0] + 1e-9 and not r.sim.physics.read().running
            await r.until(lambda: r.robot.state == "estop", what="robot in estop")
            assert "the drive reports an e-stop" in r.alarms.active[("estop", "latched")].text
            assert r.motor.state == "estop"
    run(main())


@pytest.mark.parametrize("panel", ["drive", "dispenser"])
def test_a_device_estopped_at_its_own_panel_while_idle_latches_the_other(tmp_path, panel):
    """The dispenser's went unnoticed 13 s, then a START was sent into the latch and taken for a
    fault; the drive's went unnoticed until the next move. The drive's is seen at once; the
    dispenser's at the tank, before the START (read before the move, it held every feed a round
    trip to the PLC: up to 54 farm s at 360x)."""
    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            at = r.motor.position()
            if panel == "drive":
                r.motor.press_estop()
                await r.until(lambda: r.sim.physics.estop_latched, farm_s=60.0, what="the dispenser latched")
                assert abs(r.motor.position() - at) < 1e-6
            else:
                r.sim.physics.estop()
                r.demand("T2")                                  # the next job looks before its START
                await r.until(lambda: r.motor.state == "estop", farm_s=120.0, what="the drive latched")
            await r.until(lambda: r.robot.state == "estop", what="robot in estop")
            assert r.sim.physics.runs == []
            assert f"the {panel} reports an e-stop" in r.alarms.active[("estop", "latched")].text
    run(main())


def test_a_drive_unheard_while_the_robot_waits_is_a_fault_and_recovers(tmp_path):
    """CAN silence raised no alarm while the robot was idle: it was found at the next move."""
    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            r.motor.silence()
            await r.until(lambda: r.robot.state == "fault", farm_s=600.0, what="fault")
            assert "CAN silence" in r.alarms.active[("feeder", "fault")].text
            r.motor.resume()
            await r.until(lambda: r.robot.state == "idle", farm_s=600.0, what="homed again")
            served = r.demand("T1")                          # the next job done clears the alarm
            await r.until(lambda: r.store.db.execute("SELECT outcome FROM demand WHERE id=?", (served,))
                          .fetchone()[0] == "served", farm_s=600.0, what="served")
            assert ("feeder", "fault") not in r.alarms.active
    run(main())


def test_the_drive_watch_outlives_a_bug_in_a_look(tmp_path, caplog):
    """A watch that died of one bad look would watch nothing more, and nobody would know."""
    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            real, looks = r.rail.status, []

            def flaky():
                looks.append(1)
                if len(looks) == 1:
                    raise RuntimeError("a bug")
                return real()
            r.rail.status = flaky
            await r.until(lambda: len(looks) > 1, what="a second look")
            r.motor.press_estop()
            await r.until(lambda: r.sim.physics.estop_latched, farm_s=60.0, what="the dispenser latched")
            assert r.robot.state == "estop"
    run(main())
    assert "looking at the drive's status failed" in caplog.text


def _operator_feed(r, tank: str, grams: float = 40.0) -> int:
    """As the feed override does: in the ledger first, then queued."""
    demand_id = r.store.add_demand(tank, r.clock.now(), 0.0, source="operator", grams=grams)
    r.robot.on_demand(Job(tank, r.clock.now(), demand_id, "operator", grams))
    return demand_id


def _outcome(r, demand_id: int) -> str:
    return r.store.db.execute("SELECT outcome FROM demand WHERE id = ?", (demand_id,)).fetchone()[0]


@pytest.mark.parametrize("when", ["waiting", "moving"])
def test_an_estop_withdraws_an_operators_feed_not_started_and_keeps_the_fishs_demand(tmp_path, when):
    """An operator's feed asked before an e-stop was served after the reset: whoever stopped the
    farm may have hands in a tank, and nobody asked for food after it."""
    async def main():
        async with rig(tmp_path, run=(when == "moving")) as r:
            if when == "moving":
                await r.until(lambda: r.robot.state == "idle", what="homed")
            asked = _operator_feed(r, "T2")
            fish = r.demand("T1") if when == "waiting" else None
            if when == "moving":
                await r.until(lambda: r.robot.state == "moving", what="on its way to T2")
            await r.robot.emergency_stop("operator H")
            assert _outcome(r, asked) == "estop" and "T2" not in r.robot.pending
            if fish is not None:
                assert _outcome(r, fish) == "open" and "T1" in r.robot.pending
                r.task = asyncio.create_task(r.robot.run())
            assert r.robot.operator_reset() is None
            await r.until(lambda: r.robot.state == "idle", farm_s=200, what="back to idle")
            if fish is not None:
                await r.until(lambda: _outcome(r, fish) == "served", what="the fish served after the reset")
            await r.clock.asleep(30.0)
            assert r.delivered.get("T2", 0.0) == 0.0 and {f.tank for f in r.store.feeds()} <= {"T1"}
    run(main())


def test_a_restart_under_a_standing_estop_withdraws_the_operators_feed_it_finds_open(tmp_path):
    async def main():
        async with rig(tmp_path, run=False) as r:
            asked = _operator_feed(r, "T2")
            fish = r.demand("T1")
            r.alarms.raise_("estop", "emergency stop: operator H", "critical", kind="latched")
            restarted = r.new_robot()                   # starts in estop: the alarm stands
            assert restarted.state == "estop"
            for row in r.store.open_demands():          # as the controller requeues them
                restarted.on_demand(Job(row["tank"], row["t"], row["id"], row["source"], row["grams"]))
            assert _outcome(r, asked) == "estop" and set(restarted.pending) == {"T1"}
            assert _outcome(r, fish) == "open"
    run(main())
