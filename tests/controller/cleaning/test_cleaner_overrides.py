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

    def operator_reset(self):
        if not self.lane.tripped:
            return "nothing to reset in state idle"
        self.lane.release()
        return None


def controller(rig, cleaner="rig"):
    return SimpleNamespace(cfg=SimpleNamespace(cleaning=object()), clock=rig.clock, store=rig.store,
                           robot=Robot(rig.lane), cleaner=rig.cleaner if cleaner == "rig" else cleaner)


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 30))


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
            o = Overrides(controller(r))
            await r.frames(poses(PATH[:3]))
            tripper = threading.Thread(target=r.lane.trip, args=("test",))
            tripper.start()
            tripper.join(5)
            await r.frames(poses(PATH[3:5]))
            assert r.cleaner.state == "estop" and r.thrusters.latched
            assert await o.apply("reset", {"operator": "ana"}) == {"ok": True}
            assert not r.thrusters.latched and not r.lane.tripped and r.cleaner.state == "localising"
            assert await o.apply("reset", {}) == {"ok": False, "error": "nothing to reset in state idle"}
    run(main())


@pytest.mark.parametrize("command", ["cleaner-start", "cleaner-stop", "cleaner-return"])
def test_a_cleaner_still_starting_is_said_so(tmp_path, command):
    async def main():
        async with Rig(tmp_path) as r:
            o = Overrides(controller(r, cleaner=None))
            assert await o.apply(command, {}) == {"ok": False, "error": f"command: {STARTING}"}
    run(main())
