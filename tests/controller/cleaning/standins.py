"""Honest stand-ins for the parts other branches build, to the PLAN9 interfaces: thrusters that hold
a real latch and refuse drives while latched, a camera that can go away, a tracker that coasts then
loses the float, a follower that walks its waypoints, a coverage map of cells. Each does what its
interface promises; none knows what the test expects."""
from __future__ import annotations

import asyncio
import json
import math
import threading
from dataclasses import dataclass

import numpy as np

from devices.errors import LinkDown
from devices.thrusters import EstopLatched, ThrusterState


class LatchedThrusters:
    """Holds its e-stop latch: a drive while latched is refused (and moves nothing)."""

    def __init__(self, clock, name="thrusters"):
        self.name, self.clock = name, clock
        self.latched = False
        self.down: str | None = None       # unreachable, with this text
        self.fault: str | None = None      # reports a fault of its own
        self.left = self.right = 0.0
        self.log: list[tuple] = []         # ("drive", t, left, right) | ("stop", t) | ("refused", t, ...)
        self.on_drive = None               # a test's look at the world when a drive arrives

    def _line(self):
        if self.down:
            raise LinkDown(self.name, self.down)

    async def drive(self, left, right):
        self._line()
        if self.latched:
            self.log.append(("refused", self.clock.now(), left, right))
            raise EstopLatched(self.name, "drive refused: e-stop latched")
        if self.on_drive is not None:
            self.on_drive()
        self.left, self.right = left, right
        self.log.append(("drive", self.clock.now(), left, right))

    async def stop(self):
        self._line()
        self.left = self.right = 0.0
        self.log.append(("stop", self.clock.now()))

    def trip_estop(self):
        self._line()
        self.latched = True
        self.left = self.right = 0.0
        return self.status()

    async def reset_estop(self):
        self._line()
        self.latched = False

    def status(self):
        return ThrusterState(self.clock.now(), self.left, self.right, self.latched, False, self.fault)

    def drives(self):
        return [e for e in self.log if e[0] == "drive"]


class InstantRail:
    """The feeder's drive and dispenser, latching at once (their own tests are elsewhere)."""

    def __init__(self):
        self.latched = False

    def trip_estop(self):
        self.latched = True
        return ThrusterState(0.0, 0.0, 0.0, True, False, None)

    def estop_seen_since(self, t):
        return self.latched


@dataclass(frozen=True)
class Frame:
    t: float
    image: object          # here: the true pose (x, y, heading) or None when the float is hidden
    seq: int


class ScriptedCamera:
    """Frames of a script of poses, one farm ``dt_s`` apart; ``down`` makes reads fail; at the end
    of the script reads wait until ``more`` is extended."""

    def __init__(self, clock, poses, dt_s=0.2, name="tower"):
        self.name, self.clock, self.dt_s = name, clock, dt_s
        self.poses = list(poses)
        self.seq = 0
        self.down: str | None = None
        self.fed = asyncio.Event()
        self.idle = asyncio.Event()        # set while a read waits for more of the script

    def feed(self, poses):
        self.poses.extend(poses)
        self.idle.clear()
        self.fed.set()

    def go_down(self, why):
        self.down = why
        self.fed.set()                     # a read waiting for frames hears of it

    async def read(self):
        while True:
            if self.down:
                why = self.down
                await asyncio.sleep(0)             # a read that fails still yields, as a socket's does
                raise LinkDown(self.name, why)
            if self.seq < len(self.poses):
                break
            self.fed.clear()
            self.idle.set()
            await self.fed.wait()
        self.idle.clear()
        pose = self.poses[self.seq]
        self.seq += 1
        self.clock.advance(self.dt_s)
        return Frame(self.clock.now(), pose, self.seq)


@dataclass(frozen=True)
class Fix:
    x_m: float
    y_m: float
    heading_rad: float
    confidence: float


class Detector:
    """detect_float's shape: the frame's pose as a fix; notes the threads it ran on."""

    def __init__(self):
        self.threads = set()

    def __call__(self, image, near, scan=False):
        self.threads.add(threading.current_thread())
        return None if image is None else Fix(*image, 0.9)


@dataclass(frozen=True)
class Track:
    t_s: float
    x_m: float | None
    y_m: float | None
    heading_rad: float | None
    state: str
    std_m: float | None = None
    speed_m_s: float | None = None


class CoastingTracker:
    """FloatTracker's contract: tracking on a fix, predicted (last pose) through a dropout shorter
    than ``lost_after_s``, lost after it; tracking again at once on the next fix."""

    def __init__(self, lost_after_s=2.0):
        self.lost_after_s = lost_after_s
        self.last: tuple | None = None

    def wants_scan(self, t):
        return False

    def step(self, t, fix):
        if fix is not None:
            self.last = (t, fix.x_m, fix.y_m, fix.heading_rad)
            return Track(t, fix.x_m, fix.y_m, fix.heading_rad, "tracking")
        if self.last is not None and t - self.last[0] < self.lost_after_s:
            return Track(t, *self.last[1:], "predicted")
        return Track(t, None, None, None, "lost")

    def search_region(self, t_s=None):
        return None if self.last is None else (self.last[1], self.last[2], 1.0)


@dataclass(frozen=True)
class Plan:
    path: np.ndarray


class WaypointFollower:
    """PathFollower's contract: ``progress`` is the waypoint reached (at most the last), ``done``
    once the last is reached."""

    def __init__(self, path, start_index=0, reach_m=0.3):
        self.path, self.reach_m = np.asarray(path, float), reach_m
        self.progress = min(max(int(start_index), 0), len(self.path) - 1)
        self.done = False
        self.refused: list[int] = []      # what the cleaner said of the geofence at each command

    def command(self, x, y, heading, dt_s=None, refused=0):
        self.refused.append(refused)
        while not self.done and math.dist(self.path[self.progress], (x, y)) < self.reach_m:
            if self.progress == len(self.path) - 1:
                self.done = True
            else:
                self.progress += 1
        if self.done:
            return 0.0, 0.0
        tx, ty = self.path[self.progress]
        turn = math.remainder(math.atan2(ty - y, tx - x) - heading, math.tau)
        steer = max(-0.5, min(0.5, turn))
        return 0.5 - steer, 0.5 + steer


class CellMap:
    """CoverageMap's contract on 1 m cells of a w x h pond: a sweep cleans the cells it passes."""

    def __init__(self, w=10, h=4, cells=None):
        self.w, self.h = w, h
        self.cells: set[tuple[int, int]] = set(cells or ())

    def sweep(self, x0, y0, x1, y1, heading0=None, heading1=None):
        n = max(1, int(math.dist((x0, y0), (x1, y1)) / 0.1))
        for k in range(n + 1):
            x, y = x0 + (x1 - x0) * k / n, y0 + (y1 - y0) * k / n
            if 0 <= x < self.w and 0 <= y < self.h:
                self.cells.add((int(x), int(y)))

    def coverage(self):
        return len(self.cells) / (self.w * self.h)

    def to_bytes(self):
        return json.dumps(sorted(self.cells)).encode()

    @classmethod
    def from_bytes(cls, data):
        try:
            return cls(cells=[tuple(c) for c in json.loads(data)])
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"not a coverage map: {exc}") from None
