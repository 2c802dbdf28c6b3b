"""cleaner-start / cleaner-stop / cleaner-return and reset, through Overrides.apply (validated,
acted on, audited) on a real coordinator over the stand-ins of test_cleaner."""
from __future__ import annotations

import asyncio
import threading
from types import SimpleNamespace

import pytest

from controller.overrides import STARTING, Overrides
from tests.controller.cleaning.test_cleaner import PATH, Rig, poses


class Robot:
    """The feeder as the reset sees it: in estop, it releases the lane."""

    def __init__(self, lane):
        self.lane = lane
        self.resets = 0

    @property
    def state(self):
        return "estop" if self.lane.tripped else "idle"

    def operator_reset(self):
        self.resets += 1
        if not self.lane.tripped:
            return "nothing to reset in state idle"
        self.lane.release()
        return None


def controller(rig, cleaner="rig"):
    return SimpleNamespace(cfg=SimpleNamespace(cleaning=object()), clock=rig.clock, store=rig.store, lane=rig.lane,
                           robot=Robot(rig.lane), cleaner=rig.cleaner if cleaner == "rig" else cleaner)


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 30))


async def stopped_while_cleaning(r) -> Overrides:
    """The rig's cleaner e-stopped from another thread while cleaning, every latch confirmed (a
    reset before is refused: a loaded machine's lane thread may take more than the test's next
    step); the overrides to reset it with."""
    o = Overrides(controller(r))
    await r.frames(poses(PATH[:3]))
    tripper = threading.Thread(target=r.lane.trip, args=("test",))
    tripper.start()
    tripper.join(5)
    await r.frames(poses(PATH[3:5]))
    assert r.cleaner.state == "estop"
    while r.lane.confirming(60.0):
        await asyncio.sleep(0.005)
    return o


def test_operator_commands_move_the_cleaner_and_are_audited(tmp_path):
    async def main():
        async with Rig(tmp_path) as r:
            o = Overrides(controller(r))
            assert await o.apply("cleaner-return", {"operator": "ana"}) == {
                "ok": False, "error": "cleaner is docked: cannot return"}
            assert await o.apply("cleaner-start", {"operator": "ana", "reason": "night"}) == {"ok": True}
            assert r.cleaner.state == "localising"
            await r.frames(poses(PATH[:4]))
            assert r.cleaner.state == "cleaning"
            assert await o.apply("cleaner-start", {}) == {"ok": False, "error": "cleaner is cleaning: cannot start"}
            assert await o.apply("cleaner-stop", {"speed": 1}) == {"ok": False, "error": "speed: unknown field"}
            assert await o.apply("cleaner-stop", {}, user="bob") == {"ok": True}
            assert r.cleaner.state == "manual" and r.thrusters.log[-1][0] == "stop"
            assert await o.apply("cleaner-return", {}) == {"ok": True}
            assert (r.cleaner.state, r.cleaner.machine.mission) == ("localising", "return")
            await asyncio.sleep(0)
            rows = [(a["command"], a["user"], a["ok"]) for a in r.store.audit()]
            assert rows == [("cleaner-return", None, 0), ("cleaner-start", None, 1), ("cleaner-start", None, 0),
                            ("cleaner-stop", None, 0), ("cleaner-stop", "bob", 1), ("cleaner-return", None, 1)]
    run(main())


def test_reset_releases_the_thrusters_latch_with_the_feeders(tmp_path):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            o = await stopped_while_cleaning(r)
            assert r.thrusters.latched
            assert await o.apply("reset", {"operator": "ana"}) == {"ok": True}
            assert not r.thrusters.latched and not r.lane.tripped and r.cleaner.state == "localising"
            assert await o.apply("reset", {}) == {"ok": False, "error": "nothing to reset in state idle "
                                                                         "(the cleaner is localising)"}
    run(main())


def test_two_resets_at_once_release_once_and_the_other_is_told_there_is_nothing_to_reset(tmp_path):
    """The second reset came while the first waited for the thrusters' release, and was refused
    for a latch the first had released already."""
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            o = await stopped_while_cleaning(r)
            return await asyncio.gather(o.apply("reset", {"operator": "ana"}), o.apply("reset", {"operator": "bo"}))
    first, second = run(main())
    assert first == {"ok": True}
    assert second == {"ok": False, "error": "nothing to reset in state idle (the cleaner is localising)"}


def test_a_reset_before_the_estop_is_confirmed_is_refused_and_releases_nothing(tmp_path):
    """A reset 5 ms after an e-stop cut the stops still in flight: the thrusters never stopped, and
    the e-stop answered "not confirmed" with no alarm left standing (a probe's race)."""
    class Confirming:
        tripped, released = True, False

        def confirming(self, within_s):
            return within_s > 0

    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            c = controller(r)
            c.lane = Confirming()
            c.robot = SimpleNamespace(state="estop", operator_reset=lambda: pytest.fail("the feeder was reset"))
            reply = await Overrides(c).apply("reset", {"operator": "ana"})
            await asyncio.sleep(0)                     # the audit is written just after the reply
            return reply, r.store.audit()
    reply, audit = run(main())
    assert reply == {"ok": False, "error": "reset: the e-stop is not confirmed by every device yet; reset once it "
                                           "is (within 1 s, or the estop alarm names the device)"}
    assert [(a["command"], a["ok"]) for a in audit] == [("reset", 0)]


@pytest.mark.parametrize("command", ["cleaner-start", "cleaner-stop", "cleaner-return"])
def test_a_cleaner_still_starting_is_said_so(tmp_path, command):
    async def main():
        async with Rig(tmp_path) as r:
            o = Overrides(controller(r, cleaner=None))
            assert await o.apply(command, {}) == {"ok": False, "error": f"command: {STARTING}"}
    run(main())
