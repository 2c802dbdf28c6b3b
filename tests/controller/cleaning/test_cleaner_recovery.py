"""The cleaner backing up its trail when lost (recovery.py wired into cleaner.py), on the stand-ins of
test_cleaner.py with the farm clock injected: only after ``after_s`` of ``lost``, astern, only in
``lost`` with the e-stop clear; the float back ends it (cleaning resumes); the trail's end stops
the thrusters for good; an e-stop stops it and nothing is sent after."""
from __future__ import annotations

import threading

import numpy as np

from controller.cleaning.recovery import Recovery
from tests.controller.cleaning.test_cleaner import Rig, run

TRAIL = [(float(x), 0.5, 0.0) for x in np.arange(0.5, 2.51, 0.1)]   # along the first lane, 0.1 m a frame


async def lost_with_trail(r, after_s=1.0):
    r.cleaner.recovery = Recovery(after_s=after_s)
    await r.frames(TRAIL)
    assert r.cleaner.state == "cleaning" and len(r.cleaner.recovery.trail) > 10
    await r.frames([None] * 10)                      # 2 s at 0.2 s a frame: the stand-in tracker's lost
    assert r.cleaner.state == "lost" and r.thrusters.log[-1][0] == "stop"


def lost_drives(r, since=0):
    return [e for e in r.thrusters.log[since:] if e[0] == "drive"]


def test_it_waits_recover_after_s_then_backs_up_only_in_lost_until_the_float_is_back(tmp_path):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await lost_with_trail(r, after_s=1.0)
            mark = len(r.thrusters.log)
            await r.frames([None] * 4)                   # 0.8 s of lost: still waiting
            assert lost_drives(r, mark) == [] and r.cleaner.recovery.runs == 0
            await r.frames([None] * 6)
            back = lost_drives(r, mark)
            assert back and r.cleaner.recovery.active and r.cleaner.state == "lost"
            assert all(left < 0 and right < 0 for _, _, left, right in back)   # astern, slowly
            assert all(max(abs(left), abs(right)) <= 0.5 for _, _, left, right in back)
            assert back[0][1] - r.thrusters.log[mark - 1][1] >= 1.0 - 1e-9
            await r.frames([(2.4, 0.5, 0.0)])            # seen again: the follower has it at once
            assert r.cleaner.state == "cleaning" and r.cleaner.recovery.ended["reacquired"] == 1
            assert r.thrusters.drives()[-1][2] + r.thrusters.drives()[-1][3] > 0   # ahead again
            assert all(state in ("cleaning", "returning", "lost") and not tripped for state, tripped in r.at_drive)
            assert r.states() == ["cleaning", "lost", "cleaning"]
    run(main())


def test_the_trails_end_stops_the_thrusters_and_it_drives_no_further(tmp_path):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await lost_with_trail(r)
            budget = r.cleaner.recovery.trail_length()
            await r.frames([None] * 200)                 # 40 s: 2 m at ~0.1 m/s is used up well before
            rec = r.cleaner.recovery
            assert rec.runs == 1 and rec.ended["trail_end"] == 1 and not rec.active
            assert r.thrusters.log[-1][0] == "stop" and r.cleaner.state == "lost"
            back = [e for e in lost_drives(r) if e[2] + e[3] < 0]      # the follower's are all ahead
            seconds = back[-1][1] - back[0][1]
            assert seconds * 0.25 * 0.4 <= budget + 0.2     # no longer than the trail at its speed
            mark = len(r.thrusters.log)
            await r.frames([None] * 50)
            assert lost_drives(r, mark) == []
    run(main())


def test_an_estop_during_recovery_stops_it_and_nothing_is_sent_after(tmp_path):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await lost_with_trail(r)
            await r.frames([None] * 8)
            assert r.cleaner.recovery.active and lost_drives(r)[-1][2] < 0
            tripper = threading.Thread(target=r.lane.trip, args=("operator test",))
            tripper.start()
            tripper.join(5)
            assert r.thrusters.latched
            mark = len(r.thrusters.log)
            await r.frames([None] * 20)
            assert r.cleaner.state == "estop" and r.thrusters.log[mark:] == []   # not even a refused drive
            assert not r.cleaner.recovery.active and r.cleaner.recovery.ended["interrupted"] == 1
    run(main())
