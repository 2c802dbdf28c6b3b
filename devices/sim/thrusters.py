"""The simulated thruster controller: latch, watchdog and ramps, on a pseudo-terminal.

``ThrusterTwin`` is the controller's behaviour in farm time, closed-form: the thrust each side
gives is piecewise linear (ramping at ``ramp_per_s`` towards its target), so ``thrust(t)``
answers exactly at any instant, however coarsely anyone looks. It holds the e-stop latch (an
E cuts both to zero at once and refuses every drive until R) and the watchdog (Klipper's
max_duration): a target other than zero expires ``watchdog_s`` farm seconds after the drive that
set it, and from that instant both ramp to zero and the status says ``watchdog`` — the instant
is computed, not polled for, so the physics sees the stop where it happened at any speed.

``SimThrusters`` serves it on a pty in the line protocol (devices/thrusters/protocol.py): it
answers every command (status first, then the reply), reports a status every ``status_s`` wall
seconds and at once when the watchdog trips. ``thrust`` is the physics hook (devices/sim/pond.py
steps the pond robot with it). The sim keeps its own handle on the slave open, so writes never
fail while no reader is attached; ``stop()`` closes both ends and a reader sees the port vanish.
"""
from __future__ import annotations

import asyncio
import errno
import os
import threading
import time
from collections import deque

from pydantic import BaseModel, ConfigDict, Field

from devices.sections import validate_section
from devices.sim.ptys import close_pty, end_task, open_pty, write_lines
from devices.thrusters import protocol as p

MAX_PENDING = 1 << 14            # bytes kept for a partial write before lines are dropped
HISTORY = 256                    # thrust segments kept: the physics may look a little back


class SimThrusterParams(BaseModel):
    """farm.toml ``[sim.thrusters]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    watchdog_s: float = Field(0.5, ge=0.05, le=600, description="farm s: no drive this long stops both")
    ramp_per_s: float = Field(4.0, gt=0, description="farm: fraction of full thrust gained per second")
    status_s: float = Field(0.05, gt=0, le=10, description="wall seconds between status reports")
    period_s: float = Field(0.005, gt=0, le=1, description="wall seconds between watchdog looks")


def _toward(a: float, b: float, step: float) -> float:
    return b if abs(b - a) <= step else a + (step if b > a else -step)


class ThrusterTwin:
    """The controller's state and its thrust over farm time. Thread-safe: the physics reads
    ``thrust`` from wherever it runs while commands arrive on the loop."""

    def __init__(self, params: SimThrusterParams, t0: float, truth=None):
        self.ramp = params.ramp_per_s
        self.watchdog_s = params.watchdog_s
        self.truth = truth
        self._lock = threading.Lock()
        # (start, left at start, right at start, target left, target right)
        self._segments: deque[tuple[float, float, float, float, float]] = deque(
            [(t0, 0.0, 0.0, 0.0, 0.0)], maxlen=HISTORY)
        self._last_drive = t0
        self.estop = False
        self.fault = p.Fault.NONE
        self.watchdog_tripped = False
        self.seq = 0
        self.watchdog_trips: list[float] = []     # farm instants the watchdog stopped the thrusters
        self.estops: list[float] = []

    # --- the thrust -----------------------------------------------------------------------------
    def _at(self, seg, t: float) -> tuple[float, float]:
        t0, fl, fr, tl, tr = seg
        step = self.ramp * max(0.0, t - t0)
        return _toward(fl, tl, step), _toward(fr, tr, step)

    def _segment(self, t: float):
        return next((s for s in reversed(self._segments) if s[0] <= t), self._segments[0])

    def _retarget(self, t: float, left: float, right: float, *, cut: bool = False) -> None:
        t = max(t, self._segments[-1][0])
        now = (0.0, 0.0) if cut else self._at(self._segments[-1], t)
        self._segments.append((t, *now, left, right))

    def _settle(self, t: float) -> bool:
        """Let the watchdog act if its instant has come by ``t``; True when it tripped now."""
        last = self._segments[-1]
        if self.watchdog_tripped or (last[3] == 0.0 and last[4] == 0.0):
            return False
        due = self._last_drive + self.watchdog_s
        if t < due:
            return False
        self._retarget(due, 0.0, 0.0)
        self.watchdog_tripped = True
        self.watchdog_trips.append(max(due, last[0]))
        return True

    def thrust(self, t: float) -> tuple[float, float]:
        """The thrust (left, right) the propellers actually give at farm time ``t``."""
        with self._lock:
            self._settle(t)
            return self._at(self._segment(t), t)

    def settle(self, t: float) -> bool:
        with self._lock:
            return self._settle(t)

    def status(self, t: float) -> p.Status:
        with self._lock:
            self._settle(t)
            left, right = self._at(self._segment(t), t)
            flags = ((p.FLAG_ESTOP * self.estop) | (p.FLAG_WATCHDOG * self.watchdog_tripped)
                     | (p.FLAG_FAULT * (self.fault != p.Fault.NONE)))
            return p.Status(self.seq, t, left, right, flags, int(self.fault))

    # --- commands -------------------------------------------------------------------------------
    def handle(self, line: p.Line, t: float) -> p.Result:
        """Apply one parsed command at farm time ``t``; the reply's result."""
        with self._lock:
            self._settle(t)
            result = self._apply(line, t)
            if result is p.Result.ACCEPTED:
                self.seq = line.fields[0]
            return result

    def _apply(self, line: p.Line, t: float) -> p.Result:
        kind, f = line.kind, line.fields
        if not 0 <= f[0] < 65536:
            return p.Result.BAD_VALUE
        if kind == "E":
            if not self.estop:
                self._latched(t)
            self.estop = True
            self._retarget(t, 0.0, 0.0, cut=True)
        elif kind == "R":
            self.estop, self.fault = False, p.Fault.NONE
        elif kind == "S":
            self._retarget(t, 0.0, 0.0)
        elif kind == "W":
            if not p.WATCHDOG_MS[0] <= f[1] <= p.WATCHDOG_MS[1]:
                return p.Result.BAD_VALUE
            self.watchdog_s = f[1] / 1000.0
        elif kind == "D":
            if self.estop:
                return p.Result.ESTOP
            if self.fault != p.Fault.NONE:
                return p.Result.FAULT
            if abs(f[1]) > p.FULL or abs(f[2]) > p.FULL:
                return p.Result.BAD_VALUE
            self._retarget(t, f[1] / p.FULL, f[2] / p.FULL)
            self._last_drive = t
            self.watchdog_tripped = False
        else:
            return p.Result.BAD_COMMAND
        return p.Result.ACCEPTED

    def inject_fault(self, t: float, code: int = p.Fault.OVERCURRENT) -> None:
        """The controller trips (a blocked propeller, overcurrent): power cut, drives refused until R."""
        with self._lock:
            self.fault = p.Fault(code)
            self._retarget(t, 0.0, 0.0, cut=True)

    def _latched(self, t: float) -> None:
        self.estops.append(t)
        if self.truth is not None:
            self.truth.write("estop", t, device="thrusters", wall=time.time())


class SimThrusters:
    """The twin on a pty. ``port``: the slave's path, for the ``serial`` driver."""

    def __init__(self, clock, params: SimThrusterParams | dict | None = None, truth=None, *,
                 where: str = "farm.toml"):
        if not isinstance(params, SimThrusterParams):
            params = validate_section(SimThrusterParams, params or {}, where, "sim.thrusters")
        self.params = params
        self.clock = clock
        self.twin = ThrusterTwin(params, clock.now(), truth)
        self._malformed = 0
        self.dropped = 0                # lines dropped on a full pty
        self.silent = False             # a dead controller board: hears nothing, says nothing
        self._master = self._slave = -1
        self._port = ""
        self._lines = p.Lines()
        self._pending = b""
        self._task: asyncio.Task | None = None

    @property
    def port(self) -> str:
        return self._port

    @property
    def malformed(self) -> int:
        """Command lines rejected as line noise."""
        return self._malformed + self._lines.torn

    def thrust(self, t: float) -> tuple[float, float]:
        """The physics hook: thrust (left, right) at farm time ``t``."""
        return self.twin.thrust(t)

    async def start(self) -> None:
        self._master, self._slave, self._port = open_pty()
        asyncio.get_running_loop().add_reader(self._master, self._readable)
        self._task = asyncio.create_task(self._serve(), name="sim-thrusters")

    async def stop(self) -> None:
        await end_task(self._task)
        self._task = None
        if self._master >= 0:
            asyncio.get_running_loop().remove_reader(self._master)
        close_pty(self._master, self._slave)
        self._master = self._slave = -1

    async def _serve(self) -> None:
        loop = asyncio.get_running_loop()
        next_status = 0.0
        while True:
            tripped = self.twin.settle(self.clock.now())
            if tripped or loop.time() >= next_status:
                self._send(p.status_line(self.twin.status(self.clock.now())))
                next_status = loop.time() + self.params.status_s
            await asyncio.sleep(self.params.period_s)

    def _readable(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:          # no reader attached to the slave right now
                return
            raise
        for raw in self._lines.feed(data):
            self._on_line(raw)

    def _on_line(self, raw: bytes) -> None:
        if self.silent:
            return
        line = p.parse(raw)
        if line is None or line.kind not in "DSERW":
            if raw.strip():
                self._malformed += 1
            return
        t = self.clock.now()
        result = self.twin.handle(line, t)
        out = [p.status_line(self.twin.status(t))] if result is p.Result.ACCEPTED else []
        self._send(*out, p.reply_line(line.fields[0], result))

    def _send(self, *lines: bytes) -> None:
        if self.silent or self._master < 0:
            return
        self._pending, dropped = write_lines(self._master, self._pending, lines, MAX_PENDING)
        self.dropped += dropped
