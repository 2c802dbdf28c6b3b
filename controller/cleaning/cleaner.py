"""The pond cleaner's coordinator: one frame of the tower camera at a time,

    detect the float (worker thread) -> track -> state machine -> steer -> drive -> sweep the map
    -> save (every few farm seconds, and on every state change) -> publish ``cleaner/state``.

Safety is the thrusters' own latch, set by the e-stop lane (controller.feeding.estop) with the
feeder's, and the lane's stop token: every drive checks the token and the state first, with
nothing awaited between the check and the send; a drive that slips past is refused by the latched
device, and a robot that stops hearing drives is stopped by the device's watchdog. Only in
``cleaning`` and ``returning`` are the thrusters driven, and in ``lost`` backing up along its
trail (recovery.py, no further); entering any other state stops them.

A camera or thrusters that go away are alarmed (``device/NAME``, logged once on loss and once on
recovery), the thrusters stopped, the machine put in ``fault``; when they are back it localises
again. Progress (coverage map, path index, mission) is in the ledger: a restart, even after
SIGKILL, resumes where the last save left it.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from controller.cleaning.ledger import Progress
from controller.cleaning.machine import STATES, CleanerMachine
from controller.cleaning.picture import FrozenPicture
from controller.cleaning.thruster_link import ThrusterLink
from controller.feeding.estop import Halted
from controller.ledger_writes import LedgerUnwritable
from devices.errors import DeviceError

DRIVE_LASTS_S = 0.5     # farm s a drive target lasts on the thrusters (their watchdog's default)

log = logging.getLogger("fishfarm.cleaner")

RETRY_WALL_S = 0.5          # wall seconds between reads of a camera that failed
TRACE_STEP_M = 0.05         # the trace keeps poses this far apart (the map plot needs no more)


@dataclass(frozen=True)
class Course:
    """What the cleaner needs of the plan besides the follower and map it runs: how to start a
    fresh run and how to get home. ``follow(path, start_index)`` makes a path follower;
    ``fresh_map()`` an empty coverage map; ``route_home(x, y)`` the waypoints to the dock."""
    follow: Callable
    fresh_map: Callable
    route_home: Callable
    fingerprint: str
    mop_up: Callable | None = None       # (map, x, y) -> mopup.MopUp; None: home once the lanes are done
    save_every_s: float = 5.0
    publish_every_s: float = 1.0


class Cleaner(ThrusterLink):
    def __init__(self, camera, thrusters, detector, tracker, plan, follower, coverage_map, store, clock, publish,
                 *, alarms, lane, course: Course, run: int = 1, state: str = "docked", mission: str | None = None,
                 reopen: Callable | None = None, fence=None, recovery=None,
                 frame_size: tuple[int, int] | None = None):
        self.camera, self.thrusters, self.detector, self.tracker = camera, thrusters, detector, tracker
        self.frame_size = frame_size           # (w, h) TOWER.json was fitted to; None: not said
        self.picture = FrozenPicture()
        self._drove_t = -math.inf              # farm time of the last drive with thrust
        self.reopen = reopen                   # async (device) -> a fresh one: a lost link is lost for good
        self._reopen_at = -math.inf            # monotonic: the next attempt, backing off
        self._reopen_tries = 0
        self.plan, self.follower, self.map = plan, follower, coverage_map
        self.store, self.clock, self.publish, self.alarms, self.lane = store, clock, publish, alarms, lane
        self.course, self.run_id = course, run
        self.fence = fence                     # geofence.Geofence: every drive passes it (None: tests' stand-ins)
        self.recovery = recovery               # recovery.Recovery: backs up its trail when lost (None: waits)
        self.homing = None                     # the follower of the route to the dock, while returning
        self.mopup = None                      # mopup.MopUp once the lanes are done (this process)
        self.track = None                      # the tracker's latest FloatTrack
        self._swept_from: tuple[float, float] | None = None
        self._trace: list[tuple[float, float]] = []       # poses not saved yet
        self._traced: tuple[float, float] | None = None   # the last pose kept in the trace
        self._down: dict[str, str] = {}        # device name -> why it is out
        self._must_stop = True                 # thrusters to be stopped before anything else is sent
        self._saved_t = self._published_t = -math.inf
        self._steered_t: float | None = None
        self._last_seq = None
        self.machine = CleanerMachine(state, mission, latch_released=self._latch_released,
                                      on_change=self._changed)

    @property
    def state(self) -> str:
        return self.machine.state

    # -- the frame loop ----------------------------------------------------------
    async def run(self) -> None:
        """Frames until cancelled; the thrusters are stopped on the way out (a courtesy: the
        device's watchdog stops them anyway once drives stop coming)."""
        loop = asyncio.get_running_loop()
        pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="float-detect")  # one per run()
        try:
            while True:
                frame = await self._next_frame()
                if frame is None:
                    continue
                near = self.tracker.search_region(frame.t)   # looked for where it will be now
                fix = None
                if self._picture_usable(frame):
                    scan = self.tracker.wants_scan(frame.t)    # now and then the whole frame, for spares
                    fix = await loop.run_in_executor(pool, self.detector, frame.image, near, scan)
                await self.on_track(self.tracker.step(frame.t, fix))
        finally:
            pool.shutdown(wait=False, cancel_futures=True)
            self.save()
            if not self.lane.tripped:
                try:
                    await asyncio.wait_for(self.thrusters.stop(), 1.0)
                except (DeviceError, TimeoutError, Halted) as exc:
                    log.warning("cleaner: thrusters not stopped on the way out: %s", exc)

    async def _next_frame(self):
        try:
            frame = await self.camera.read()
        except DeviceError as exc:
            return await self._no_frame(exc.text)
        if self.frame_size is not None and tuple(frame.image.shape[1::-1]) != tuple(self.frame_size):
            w, h = frame.image.shape[1::-1]
            return await self._no_frame(f"frames {w}x{h}, TOWER.json was fitted to {self.frame_size[0]}x"
                                        f"{self.frame_size[1]}: its positions would be metres off")
        self._device_up(self.camera.name)
        if frame.seq == self._last_seq:        # nothing new yet: no second look at the same frame
            await asyncio.sleep(0.005)
            return None
        self._last_seq = frame.seq
        return frame

    def _picture_usable(self, frame) -> bool:
        """No fix from a picture frozen while the robot drives (controller/cleaning/picture.py):
        the track coasts, the robot stops, and the alarm stands until the picture changes."""
        was = self.picture.frozen
        driving = frame.t - self._drove_t <= DRIVE_LASTS_S
        usable = self.picture.usable(frame.t, frame.image, driving)
        if self.picture.frozen and not was:
            self.alarms.raise_(f"device/{self.camera.name}", "the picture is frozen (the same frame while the robot "
                               "drives): no fix taken from it", kind="frozen")
        elif was and not self.picture.frozen:
            self.alarms.clear(f"device/{self.camera.name}", "the picture moves again", kind="frozen")
        return usable

    async def _no_frame(self, why: str) -> None:
        """The camera down or its frames unusable: stopped, and the track coasts (predicted, then
        lost without a position) so the state published is no stale "tracking" pose."""
        self._device_down(self.camera.name, why)
        if self.track is not None:
            self.track = self.tracker.step(max(self.clock.now(), self.track.t_s), None)
            self._publish()
        await self._halt()
        await asyncio.sleep(RETRY_WALL_S)
        return None

    async def on_track(self, track) -> None:
        """One tracker output: events to the machine, then steer, drive, sweep, save, publish."""
        self.track = track
        self._hear_estop()
        self._sweep(track)                     # the brush moved here in the state it was in
        if track.state == "tracking":
            self.machine.fire("float_tracking")
        elif track.state == "lost":
            self.machine.fire("float_lost")
        if self.recovery is not None:
            self.recovery.note(track, self.state == "lost")
        if self.state == "fault" and self.thrusters.name in self._down:
            await self._try_thrusters()
        command = self._steer(track)
        if command is not None:
            await self._drive(*command)
        else:
            await self._halt()
        self._mark(track)
        now = self.clock.now()
        if now - self._saved_t >= self.course.save_every_s:
            self.save()
        if now - self._published_t >= self.course.publish_every_s:
            self._publish()

    def _steer(self, track) -> tuple[float, float] | None:
        """(left, right) while cleaning or returning with a pose, or backing up when lost; None: stop
        (and at once while the picture is frozen: no pose, predicted or recalled, is to be trusted)."""
        if self.picture.frozen:
            self._steered_t = None
            return None
        if not self.machine.moving or track.x_m is None:
            self._steered_t = None
            backing = self.state == "lost" and self.recovery is not None
            return self.recovery.command(self.clock.now()) if backing else None
        dt = None if self._steered_t is None else max(1e-3, track.t_s - self._steered_t)
        self._steered_t = track.t_s
        refused = 0 if self.fence is None else self.fence.streak    # the follower gives such aims up
        if self.state == "cleaning":
            command = self.follower.command(track.x_m, track.y_m, track.heading_rad, dt_s=dt, refused=refused)
            if self.follower.done:               # the lanes done: the mop-up (mopup.py), then home
                command = self._mop_up(track, dt, refused)
            if command is None:
                self.machine.fire("path_done")       # -> returning: the route home is made on entry
            return command
        if self.homing is None:
            self.homing = self.course.follow(self.course.route_home(track.x_m, track.y_m), 0)
        command = self.homing.command(track.x_m, track.y_m, track.heading_rad, dt_s=dt, refused=refused)
        if self.homing.done:
            self.machine.fire("path_done")           # -> docked
            return None
        return command

    def _mop_up(self, track, dt, refused) -> tuple[float, float] | None:
        """The mop-up's command; None once it is over (or there is none). Planned from the map
        on the first call, so a restarted controller plans again from the saved one."""
        if self.course.mop_up is None:
            return None
        if self.mopup is None:
            self.mopup = self.course.mop_up(self.map, track.x_m, track.y_m)
        return self.mopup.command(track.x_m, track.y_m, track.heading_rad, dt_s=dt, refused=refused)

    def _sweep(self, track) -> None:
        """Before the track's events: the brush cleaned from the last measured pose to this one if
        the robot was cleaning on the way."""
        if self.state == "cleaning" and track.state == "tracking" and self._swept_from is not None:
            x0, y0, h0 = self._swept_from
            self.map.sweep(x0, y0, track.x_m, track.y_m, h0, track.heading_rad)

    def _mark(self, track) -> None:
        """After them: where the next sweep starts, and the trace."""
        if self.state != "cleaning":
            self._swept_from = None
            return
        if track.state != "tracking":          # coasting: the next fix sweeps from the last one
            return
        self._swept_from = (track.x_m, track.y_m, track.heading_rad)
        here = (track.x_m, track.y_m)
        if self._traced is None or math.dist(self._traced, here) >= TRACE_STEP_M:
            self._trace.append(here)
            self._traced = here

    # -- e-stop -------------------------------------------------------------------
    def _hear_estop(self) -> None:
        if self.lane.tripped and self.state != "estop":
            self.stopped(self.lane.reason or "e-stop")

    def stopped(self, reason: str) -> None:
        """The cleaner's side of an e-stop the lane has latched already: state, nothing sent."""
        if self.state != "estop":
            log.warning("cleaner: e-stop (%s)", reason)
            self.machine.estop()

    async def operator_reset(self) -> str | None:
        """Release the thrusters' latch and leave ``estop`` once the device shows it released.
        An error text, or None."""
        if self.state != "estop":
            return f"cleaner: nothing to reset in state {self.state}"
        if self.lane.tripped:
            self.lane.release()
        try:
            await self.thrusters.reset_estop()
        except DeviceError as exc:
            return f"cleaner: thrusters latch not reset: {exc.text}"
        if not self.machine.reset():
            return "cleaner: the thrusters still report their e-stop latch"
        self._must_stop = True
        await self._halt()
        return None

    # -- operator commands --------------------------------------------------------
    async def start(self) -> str | None:
        if not self.machine.allows("start"):
            return f"cleaner is {self.state}: cannot start"
        if self.follower.done:                 # the last run finished: a fresh one
            self.run_id = self.store.next_cleaner_run()
            self.map = self.course.fresh_map()
            self.follower = self.course.follow(self.plan.path, 0)
            self.mopup = None
            self._trace.clear()
            self._traced = None
            log.info("cleaner: run %d begins on a fresh map", self.run_id)
        self.machine.start()
        return None

    async def stop(self) -> str | None:
        if not self.machine.allows("stop"):
            return f"cleaner is {self.state}: nothing to stop"
        self.machine.stop()
        await self._halt()
        return None

    async def go_home(self) -> str | None:
        if not self.machine.allows("go_home"):
            return f"cleaner is {self.state}: cannot return"
        self.machine.go_home()
        return None

    # -- news and the record ------------------------------------------------------
    @property
    def path_index(self) -> int:
        """The coverage path's waypoint reached; its length once the run is done."""
        return len(self.plan.path) if self.follower.done else int(self.follower.progress)

    def _changed(self, state: str) -> None:
        if state != "returning":
            self.homing = None
        if state not in ("cleaning", "returning"):
            self._must_stop = True
        self._publish()
        try:
            asyncio.get_running_loop().call_soon(self.save)   # no fsync on the way of an e-stop
        except RuntimeError:                                  # no loop (a tool): now
            self.save()

    def snapshot(self) -> dict:
        track = self.track
        pos = track is not None and track.x_m is not None

        def r(v, nd=3):
            return None if v is None else round(float(v), nd)
        return {"t": self.clock.iso(), "state": self.state,
                "x_m": r(track.x_m) if pos else None, "y_m": r(track.y_m) if pos else None,
                "heading_rad": r(track.heading_rad, 4) if pos else None,
                "coverage": round(float(self.map.coverage()), 4),
                "tracking": None if track is None else track.state,
                "path_index": self.path_index, "mission": self.machine.mission,
                "state_code": STATES.index(self.state), "phase": self.phase}

    @property
    def phase(self) -> str | None:
        """While cleaning: ``lanes`` (the coverage path) or ``mopup`` (mopup.py, the map's say)."""
        if self.state != "cleaning":
            return None
        return "mopup" if self.follower.done else "lanes"

    def _publish(self) -> None:
        self._published_t = self.clock.now()
        try:                                   # news, not the record: never let it stop a move
            self.publish("cleaner/state", self.snapshot())
        except Exception as exc:
            log.warning("cleaner state not published: %s", exc)

    def save(self) -> None:
        """The map, the path index, state and mission, and the trace since the last save: one commit."""
        self._saved_t = self.clock.now()
        trace = np.array(self._trace) if self._trace else None
        progress = Progress(self.course.fingerprint, self.run_id, self.map.to_bytes(), self.path_index,
                            self.state, self.machine.mission, float(self.map.coverage()), self._saved_t)
        try:
            self.store.save_cleaner(progress, trace)
        except LedgerUnwritable:     # the ledger alarm says it; the trace waits for the next save
            return
        except Exception:
            log.exception("cleaner: progress not saved")
            return
        self._trace.clear()
