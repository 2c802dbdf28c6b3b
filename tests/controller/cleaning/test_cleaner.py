"""The cleaner's coordinator on stand-ins of its parts (tests/controller/cleaning/standins.py), a
real ledger, real alarms and the real e-stop lane, with the farm clock injected: it drives only in
cleaning and returning with the e-stop clear; it stops the thrusters when the float is lost, a
device goes away or the e-stop trips; it publishes every state change at once; and after a kill
it resumes the saved map and path index."""
from __future__ import annotations

import asyncio
import dataclasses
import threading

import numpy as np
import pytest

from controller.alarms import Alarms
from controller.cleaning import cleaner as cleaner_mod
from controller.cleaning import thruster_link
from controller.cleaning.cleaner import Cleaner, Course
from controller.cleaning.ledger import resume
from controller.feeding.estop import EstopLane, Latch
from controller.store import Store
from devices.clock import ManualClock
from devices.errors import LinkDown
from tests.controller.cleaning.standins import (
    CellMap,
    CoastingTracker,
    Detector,
    InstantRail,
    LatchedThrusters,
    Plan,
    ScriptedCamera,
    WaypointFollower,
)
from tests.devices.waits import until

DOCK = (0.5, 0.5)
# four lanes over a 10 m x 4 m pond, 1 m apart, boustrophedon
PATH = np.array([(x + 0.5, y + 0.5) for y in range(4) for x in (range(10) if y % 2 == 0 else range(9, -1, -1))])
MOVING = ("cleaning", "returning")


def poses(path, heading=0.0):
    return [(float(x), float(y), heading) for x, y in path]


class Rig:
    def __init__(self, tmp_path, *, state="docked", mission=None, run=1, follower=None, cmap=None, fingerprint="fp"):
        self.tmp_path = tmp_path
        self.clock = ManualClock()
        self.store = Store(tmp_path / "ledger.db")
        self.published: list[tuple[str, dict]] = []
        self.alarms = Alarms(self.store, lambda key, payload, reliable=False: self.published.append((key, payload)),
                             self.clock)
        self.thrusters = LatchedThrusters(self.clock)
        self.rail, self.dispenser = InstantRail(), InstantRail()
        self.lane = EstopLane(self.rail, self.dispenser, Latch("thrusters", self.thrusters))
        self.camera = ScriptedCamera(self.clock, [])
        self.detector = Detector()
        self.course = Course(follow=WaypointFollower, fresh_map=CellMap,
                             route_home=lambda x, y: np.array([(x, y), DOCK]), fingerprint=fingerprint,
                             save_every_s=5.0, publish_every_s=1.0)
        self.cleaner = Cleaner(self.camera, self.thrusters, self.detector, CoastingTracker(2.0), Plan(PATH),
                               follower or WaypointFollower(PATH), cmap or CellMap(), self.store, self.clock,
                               self.publish, alarms=self.alarms, lane=self.lane, course=self.course, run=run,
                               state=state, mission=mission)
        self.task: asyncio.Task | None = None
        self.at_drive: list[tuple[str, bool]] = []
        self.thrusters.on_drive = lambda: self.at_drive.append((self.cleaner.state, self.lane.tripped))

    def publish(self, key, payload, reliable=False):
        self.published.append((key, payload))

    def states(self) -> list[str]:
        out = []
        for key, p in self.published:
            if key == "cleaner/state" and (not out or out[-1] != p["state"]):
                out.append(p["state"])
        return out

    async def __aenter__(self):
        self.task = asyncio.create_task(self.cleaner.run())
        return self

    async def __aexit__(self, *exc):
        self.task.cancel()
        await asyncio.gather(self.task, return_exceptions=True)
        self.lane.close()
        self.store.close()

    async def frames(self, seq):
        self.camera.feed(list(seq))
        await asyncio.wait_for(self.camera.idle.wait(), 10)
        await asyncio.sleep(0)              # the saves scheduled by the last state change


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 30))


@pytest.fixture(autouse=True)
def quick_retries(monkeypatch):
    monkeypatch.setattr(cleaner_mod, "RETRY_WALL_S", 0.001)


def test_drives_only_while_cleaning_or_returning_and_a_run_ends_docked(tmp_path):
    async def main():
        async with Rig(tmp_path) as r:
            await r.frames(poses(PATH[:5]))                 # seen, docked: nothing moves
            assert r.cleaner.state == "docked" and r.thrusters.drives() == []
            assert await r.cleaner.start() is None
            assert r.cleaner.state == "localising"
            await r.frames([None] * 3)                      # no fix yet: localising, still
            assert r.cleaner.state == "localising" and r.thrusters.drives() == []
            await r.frames(poses(PATH))
            assert r.cleaner.follower.done and r.cleaner.state == "returning"
            await r.frames(poses([PATH[-1], (2.0, 0.5), DOCK]))
            assert r.cleaner.state == "docked" and r.cleaner.machine.mission is None
            assert r.at_drive and all(state in MOVING and not tripped for state, tripped in r.at_drive)
            assert r.thrusters.log[-1][0] == "stop"         # docked: stopped
            assert r.cleaner.map.coverage() == 1.0          # every lane swept
            assert r.states() == ["docked", "localising", "cleaning", "returning", "docked"]
            assert threading.main_thread() not in r.detector.threads and r.detector.threads
    run(main())


def test_a_lost_float_stops_the_thrusters_until_it_is_back_then_cleaning_resumes(tmp_path):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await r.frames(poses(PATH[:6]))
            assert r.cleaner.state == "cleaning"
            index = r.cleaner.follower.progress
            await r.frames([None] * 5)                      # 1 s: coasting on the prediction
            assert r.cleaner.state == "cleaning" and r.cleaner.track.state == "predicted"
            drives = len(r.thrusters.drives())
            await r.frames([None] * 10)                     # past lost_after_s
            assert r.cleaner.state == "lost" and r.thrusters.log[-1][0] == "stop"
            stopped_at = len(r.thrusters.drives())
            await r.frames([None] * 20)
            assert len(r.thrusters.drives()) == stopped_at and r.cleaner.follower.progress == index
            assert stopped_at >= drives
            await r.frames(poses(PATH[6:9]))                # back: resumes at once, from where it was
            assert r.cleaner.state == "cleaning" and len(r.thrusters.drives()) > stopped_at
            assert r.states() == ["cleaning", "lost", "cleaning"]
    run(main())


SETUPS = {"docked": None, "localising": "clean", "cleaning": "clean", "returning": "return", "lost": "clean",
          "fault": "clean", "manual": "clean"}


@pytest.mark.parametrize("state", list(SETUPS))
def test_estop_from_every_state_latches_the_thrusters_and_nothing_is_sent_after(tmp_path, state):
    async def main():
        async with Rig(tmp_path, state=state, mission=SETUPS[state]) as r:
            await r.frames(poses(PATH[:3]))
            tripper = threading.Thread(target=r.lane.trip, args=("operator test",))   # the Zenoh thread
            tripper.start()
            tripper.join(5)
            assert r.thrusters.latched and r.rail.latched and r.dispenser.latched
            log_len = len(r.thrusters.log)
            await r.frames(poses(PATH[3:8]))
            assert r.cleaner.state == "estop"
            assert r.thrusters.log[log_len:] == []          # not a drive, not even a refused one
            assert await r.cleaner.start() is not None and r.cleaner.state == "estop"
            r.thrusters.latched = True
            r.lane.release()                                # the feeder's reset came first
            assert await r.cleaner.operator_reset() is None and not r.thrusters.latched
            assert r.cleaner.state == ("localising" if r.cleaner.machine.mission else "docked")
            assert r.states()[-2:] == ["estop", r.cleaner.state]
    run(main())


def test_the_thrusters_own_estop_trips_the_whole_lane(tmp_path):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await r.frames(poses(PATH[:3]))
            r.thrusters.latched = True                      # its own button
            await r.frames(poses(PATH[3:6]))
            assert r.cleaner.state == "estop" and r.lane.tripped
            # the lane latches the others from its own thread: nothing on the e-stop path waits for it
            # (asserted at once, a run under load saw them not latched yet)
            await until(lambda: r.rail.latched and r.dispenser.latched, what="the lane's latches")
            assert [e[0] for e in r.thrusters.log].count("refused") == 1
    run(main())


def test_reset_waits_for_the_thrusters_to_show_their_latch_released(tmp_path):
    async def main():
        async with Rig(tmp_path, state="estop", mission="clean") as r:
            r.thrusters.latched = True

            async def stuck():
                pass                                        # a reset the device ignores
            r.thrusters.reset_estop = stuck
            assert "still report" in await r.cleaner.operator_reset() and r.cleaner.state == "estop"
    run(main())


@pytest.mark.parametrize("device", ["camera", "thrusters"])
def test_a_device_lost_is_alarmed_once_stops_the_thrusters_and_recovery_resumes(tmp_path, device):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await r.frames(poses(PATH[:4]))
            assert r.cleaner.state == "cleaning"
            part = r.camera if device == "camera" else r.thrusters
            if device == "camera":
                r.camera.go_down("connection refused")
                while r.cleaner.state != "fault":
                    await asyncio.sleep(0.001)
                for _ in range(20):                         # many failed reads, still one alarm
                    await asyncio.sleep(0.002)
            else:
                r.thrusters.down = "connection refused"
                await r.frames(poses(PATH[4:12]))
            assert r.cleaner.state == "fault"
            source = f"device/{part.name}"
            assert [a["active"] for a in r.store.alarms() if a["source"] == source] == [1]
            drives = len(r.thrusters.drives())
            part.down = None
            await r.frames(poses(PATH[4:10]))
            assert [a["active"] for a in r.store.alarms() if a["source"] == source] == [1, 0]
            assert r.cleaner.state == "cleaning" and len(r.thrusters.drives()) > drives
            assert r.states() == ["cleaning", "fault", "localising", "cleaning"]
            assert all(state in MOVING for state, _ in r.at_drive)
    run(main())


def test_operator_stop_holds_still_and_return_goes_home(tmp_path):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await r.frames(poses(PATH[:4]))
            assert await r.cleaner.stop() is None and r.cleaner.state == "manual"
            assert r.thrusters.log[-1][0] == "stop"
            drives = len(r.thrusters.drives())
            await r.frames(poses(PATH[4:8]))
            assert len(r.thrusters.drives()) == drives
            assert await r.cleaner.go_home() is None and r.cleaner.state == "localising"
            await r.frames(poses([PATH[7], (4.0, 0.5), (2.0, 0.5), DOCK]))
            assert r.cleaner.state == "docked"
            assert await r.cleaner.go_home() is not None    # home already: refused, by state
    run(main())


def test_progress_is_saved_and_a_killed_controller_resumes_map_and_path_index(tmp_path):
    async def main():
        r = Rig(tmp_path, state="localising", mission="clean")
        task = asyncio.create_task(r.cleaner.run())
        await r.frames(poses(PATH[:25]))                    # 5 farm s: saved at least once
        saved = r.store.cleaner_progress()
        assert saved is not None and saved.mission == "clean" and 0 < saved.path_index <= r.cleaner.follower.progress
        task.cancel()                                       # SIGKILL: no goodbye save is counted on
        await asyncio.gather(task, return_exceptions=True)
        r.lane.close()
        r.store.close()
        store = Store(tmp_path / "ledger.db")                # the new process
        saved = store.cleaner_progress()
        back = resume(store, r.course, Plan(PATH), CellMap.from_bytes, estop_standing=False, autostart=False)
        assert (back.state, back.mission, back.run) == ("localising", "clean", saved.run)
        assert back.follower.progress == saved.path_index and back.map.to_bytes() == saved.map
        trace = store.cleaner_trace(saved.run)
        assert len(trace) >= 2 and np.allclose(trace[0], PATH[0])
        store.close()
        r2 = Rig(tmp_path, state=back.state, mission=back.mission, run=back.run, follower=back.follower,
                 cmap=back.map)
        async with r2:
            await r2.frames(poses(PATH[saved.path_index:]))  # it carries on from there to the end
            assert r2.cleaner.follower.done and r2.cleaner.map.coverage() == 1.0
            assert r2.cleaner.state == "returning"
    run(main())


def test_resume_takes_a_fresh_map_for_a_changed_pond_and_estop_stands_across_restarts(tmp_path):
    from controller.cleaning.ledger import Progress
    store = Store(tmp_path / "ledger.db")
    course = Course(follow=WaypointFollower, fresh_map=CellMap, route_home=None, fingerprint="new")
    store.save_cleaner(Progress("old", 3, CellMap(cells=[(1, 1)]).to_bytes(), 12, "cleaning", "clean", 0.1, 1.0))
    fresh = resume(store, course, Plan(PATH), CellMap.from_bytes, estop_standing=False, autostart=False)
    assert (fresh.state, fresh.follower.progress, fresh.map.coverage(), fresh.run) == ("docked", 0, 0.0, 4)
    auto = resume(store, course, Plan(PATH), CellMap.from_bytes, estop_standing=False, autostart=True)
    assert (auto.state, auto.mission) == ("localising", "clean")
    stopped = resume(store, course, Plan(PATH), CellMap.from_bytes, estop_standing=True, autostart=True)
    assert stopped.state == "estop"
    store.save_cleaner(Progress("new", 3, b"garbage", 12, "cleaning", "clean", 0.5, 1.5))
    spoilt = resume(store, course, Plan(PATH), CellMap.from_bytes, estop_standing=False, autostart=False)
    assert (spoilt.state, spoilt.follower.progress, spoilt.map.coverage()) == ("docked", 0, 0.0)
    store.save_cleaner(Progress("new", 3, None, len(PATH), "docked", None, 1.0, 2.0))
    done = resume(store, course, Plan(PATH), CellMap.from_bytes, estop_standing=False, autostart=True)
    assert done.state == "docked" and done.follower.done          # a finished run is not restarted by itself
    store.close()


def test_state_payload_has_the_contract_fields(tmp_path):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await r.frames(poses(PATH[:12]))                # 2.4 farm s: periodic ones besides the change
            payloads = [p for k, p in r.published if k == "cleaner/state"]
            assert len(payloads) >= 3 and len({p["x_m"] for p in payloads}) >= 3
            for payload in payloads:
                assert {"t", "state", "x_m", "y_m", "heading_rad", "coverage"} <= set(payload)
                assert payload["state"] == "cleaning" and (payload["x_m"], payload["y_m"]) in map(tuple, PATH[:12])
            assert 0 < payloads[-1]["coverage"] < 1
    run(main())


def test_a_run_that_crashed_can_be_run_again_as_the_supervisor_does(tmp_path):
    async def main():
        r = Rig(tmp_path, state="localising", mission="clean")
        real = r.cleaner.detector
        calls = []

        def flaky(image, near, scan=False):
            calls.append(1)
            if len(calls) == 1:
                raise RuntimeError("a bug in detection")
            return real(image, near, scan)
        r.cleaner.detector = flaky
        r.camera.feed(poses(PATH[:1]))
        with pytest.raises(RuntimeError):
            await r.cleaner.run()
        async with r:                                       # the supervisor's second run()
            await r.frames(poses(PATH[1:5]))
            assert r.cleaner.state == "cleaning" and r.thrusters.drives()
    run(main())


def test_thrusters_whose_link_is_lost_for_good_are_replaced_and_the_lane_latches_the_new_ones(tmp_path):
    """A real driver's LinkDown is for good (devices/thrusters): the cleaner asks for a fresh
    driver (backing off), resumes with it, and an e-stop then latches the fresh one."""
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            fresh: list[LatchedThrusters] = []

            async def reopen(old):
                if len(fresh) < 1:                     # the first attempt finds the port not back yet
                    fresh.append(None)
                    raise LinkDown(old.name, "no such port")
                new = LatchedThrusters(r.clock)
                new.on_drive = old.on_drive
                r.lane.replace_device(old, new)
                fresh.append(new)
                return new

            r.cleaner.reopen = reopen
            await r.frames(poses(PATH[:4]))
            assert r.cleaner.state == "cleaning"
            r.thrusters.down = "port vanished"            # and it never comes back on this driver
            await r.frames(poses(PATH[4:8]))
            assert r.cleaner.state == "fault" and fresh == [None]
            thruster_link.REOPEN_WALL_S, saved = (0.0,), thruster_link.REOPEN_WALL_S
            try:
                r.cleaner._reopen_at = 0.0                 # the back-off has passed
                await r.frames(poses(PATH[8:14]))
            finally:
                thruster_link.REOPEN_WALL_S = saved
            new = fresh[-1]
            assert r.cleaner.thrusters is new and r.cleaner.state == "cleaning" and new.drives()
            assert await asyncio.wait_for(asyncio.wrap_future(r.lane.trip("test e-stop")), 5)
            assert new.latched


def test_every_drive_passes_the_geofence_and_goes_as_it_says(tmp_path):
    class Fence:                       # refuses everything: a turn on the spot instead
        def __init__(self):
            self.seen = []
            self.streak = 0

        def check(self, track, command, now_s):
            self.seen.append((track, command, now_s))
            self.streak += 1
            return 0.25, -0.25

    async def main():
        async with Rig(tmp_path) as r:
            r.cleaner.fence = fence = Fence()
            await r.cleaner.start()
            await r.frames(poses(PATH[:6]))
            drives = r.thrusters.drives()
            assert drives and all((left, right) == (0.25, -0.25) for _, _, left, right in drives)
            assert len(fence.seen) == len(drives)
            assert all(track is not None and track.x_m is not None for track, _, _ in fence.seen)
            # the follower hears how many of its commands in a row the fence has refused so far
            told = r.cleaner.follower.refused
            assert told[0] == 0 and told[1:len(drives)] == list(range(1, len(drives)))
    run(main())


class ScriptedMopUp:
    """mopup.MopUp's face to the cleaner: ``n`` commands, then None (over). (The real one's account
    in the map across a restart: test_mopup.py.)"""

    def __init__(self, cmap, n):
        self.map, self.left = cmap, n
        self.given = 0

    def command(self, x, y, heading, dt_s=None, refused=0):
        if self.given >= self.left:
            return None
        self.given += 1
        return 0.3, 0.3


def test_after_the_lanes_the_mopup_drives_in_cleaning_and_a_restart_takes_it_up_again(tmp_path):
    made = []

    def mop_up(cmap, x, y):
        made.append(ScriptedMopUp(cmap, 4))
        return made[-1]

    async def main():
        r = Rig(tmp_path, state="localising", mission="clean")
        r.cleaner.course = r.course = dataclasses.replace(r.course, mop_up=mop_up)
        task = asyncio.create_task(r.cleaner.run())
        await r.frames(poses(PATH))
        assert r.cleaner.follower.done and r.cleaner.state == "cleaning" and len(made) == 1
        assert r.cleaner.snapshot()["phase"] == "mopup" and r.cleaner.path_index == len(PATH)
        drives = len(r.thrusters.drives())
        await r.frames(poses([PATH[-1]] * 2))
        assert len(r.thrusters.drives()) == drives + 2 and r.thrusters.drives()[-1][2:] == (0.3, 0.3)
        r.cleaner.save()
        task.cancel()                                       # SIGKILL mid-mop-up
        await asyncio.gather(task, return_exceptions=True)
        r.lane.close()
        r.store.close()
        store = Store(tmp_path / "ledger.db")
        back = resume(store, r.course, Plan(PATH), CellMap.from_bytes, estop_standing=False, autostart=True)
        store.close()
        assert (back.state, back.mission) == ("localising", "clean") and back.follower.done
        r2 = Rig(tmp_path, state=back.state, mission=back.mission, run=back.run, follower=back.follower,
                 cmap=back.map)
        r2.cleaner.course = dataclasses.replace(r2.course, mop_up=mop_up)
        async with r2:
            await r2.frames(poses([PATH[-1]] * 3))
            assert len(made) == 2 and made[1].map is r2.cleaner.map      # planned again, from the saved map
            assert r2.cleaner.state == "cleaning" and r2.cleaner.snapshot()["phase"] == "mopup"
            await r2.frames(poses([PATH[-1]] * 3))
            assert r2.cleaner.state == "returning" and r2.cleaner.snapshot()["phase"] is None
    run(main())


def test_without_a_mopup_the_lanes_end_in_returning_and_the_phase_says_lanes_while_cleaning(tmp_path):
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await r.frames(poses(PATH[:3]))
            assert r.cleaner.snapshot()["phase"] == "lanes"
            await r.frames(poses(PATH[3:]))
            assert r.cleaner.state == "returning"
    run(main())


def test_a_camera_that_has_not_opened_yet_holds_the_cleaner_in_fault_until_its_frames_come(tmp_path):
    """The controller's start tells the cleaner of a device that does not open (it said localising
    for as long as the camera stayed away)."""
    async def main():
        r = Rig(tmp_path, state="localising", mission="clean")
        r.cleaner.unavailable(r.camera.name, "cannot open: no such file")
        state = r.cleaner.state
        async with r:
            await r.frames(poses(PATH[:4]))
            return state, r.cleaner.state, [a["active"] for a in r.store.alarms()
                                            if a["source"] == f"device/{r.camera.name}"], r.states()
    before, after, alarm, states = run(main())
    assert before == "fault" and after == "cleaning"
    assert alarm == [1, 0] and states[-2:] == ["localising", "cleaning"]


def test_a_camera_gone_leaves_no_stale_tracking_pose_published(tmp_path):
    """The camera stalled: the thrusters stop, and what is published coasts with the farm clock
    (predicted, then lost without a position), not "tracking" at the last pose for as long as it lasts."""
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await r.frames(poses(PATH[:4]))
            assert r.cleaner.state == "cleaning" and r.published[-1][1]["tracking"] == "tracking"
            r.camera.go_down("no frame in 2 s")
            await until(lambda: r.cleaner.state == "fault")
            await until(lambda: r.cleaner.snapshot()["tracking"] == "predicted")
            r.clock.advance(3.0)                                   # past the tracker's lost_after_s
            await until(lambda: r.cleaner.snapshot()["tracking"] == "lost")
            snap = [p for k, p in r.published if k == "cleaner/state"][-1]
            assert snap["tracking"] == "lost" and snap["x_m"] is None and snap["y_m"] is None
            r.camera.down = None
            await r.frames(poses(PATH[4:8]))
            assert r.cleaner.snapshot()["tracking"] == "tracking" and r.cleaner.state == "cleaning"
    run(main())


class SizedPose(tuple):
    """A ScriptedCamera picture (the true pose) that says its size, as a frame's image does."""
    shape = (360, 640, 3)


def test_frames_of_another_size_than_tower_json_s_are_a_fault_not_steered_on(tmp_path):
    async def main():
        r = Rig(tmp_path, state="localising", mission="clean")
        r.cleaner.frame_size = (1280, 720)
        async with r:
            r.camera.feed([SizedPose(p) for p in poses(PATH[:4])])
            await until(lambda: r.cleaner.state == "fault")
            assert r.thrusters.drives() == [] or all(d == (0.0, 0.0) for d in r.thrusters.drives())
            [alarm] = [a for a in r.store.alarms() if a["source"] == "device/tower"]
            assert "640x360" in alarm["text"] and "1280x720" in alarm["text"]
    run(main())


def test_a_picture_frozen_while_the_robot_drives_gives_no_fix_until_it_moves_again(tmp_path):
    """An encoder that froze sends its last picture again and again: under thrust the robot must
    change what the camera sees, so the same picture for a second while it drives is frozen — no
    fix from it (the track coasts, the robot stops), an alarm until the picture changes."""
    async def main():
        async with Rig(tmp_path, state="localising", mission="clean") as r:
            await r.frames(poses(PATH[:4]))
            assert r.cleaner.state == "cleaning"
            drives = len(r.thrusters.drives())
            stuck = poses(PATH[3:4]) * 10                          # 2 s of one picture at 0.2 s a frame
            await r.frames(stuck)
            frozen = [a for a in r.store.alarms() if a["source"] == "device/tower" and "frozen" in a["text"]]
            assert [a["active"] for a in frozen] == [1]
            assert r.cleaner.snapshot()["tracking"] != "tracking"
            assert len(r.thrusters.drives()) - drives <= 6          # a second of drives at most, then none
            await r.frames(poses(PATH[4:8]))                      # it moves again
            told = [(a["active"], a["text"]) for a in r.store.alarms() if a["source"] == "device/tower"]
            assert [active for active, _ in told] == [1, 0] and "moves again" in told[1][1]
            assert r.cleaner.state == "cleaning" and r.cleaner.snapshot()["tracking"] == "tracking"
    run(main())


def test_a_still_pond_with_the_robot_standing_is_no_frozen_camera(tmp_path):
    """A calm pond, a camera with noise reduction, the simulator with noise 0: the same picture frame
    after frame while nothing drives. Taken as it is (the camera driver dropped such frames for a day,
    and a docked cleaner faulted within 2 s and could not be started)."""
    async def main():
        async with Rig(tmp_path, state="docked") as r:
            await r.frames(poses(PATH[:1]) * 30)                    # 6 s of one picture, docked
            assert r.cleaner.state == "docked" and r.cleaner.snapshot()["tracking"] == "tracking"
            assert not [a for a in r.store.alarms() if a["source"] == "device/tower"]
            assert await r.cleaner.start() is None
            await r.frames(poses(PATH[:6]))
            assert r.cleaner.state == "cleaning"
    run(main())
