"""The rail drive's physical twin: a carriage on a rail and the motor controller that moves it.

Motion is trapezoidal (accelerate, cruise, decelerate; ``devices.sim.rail_motion``), planned as a few
constant-acceleration phases from the carriage's position *and velocity* at the instant of a command, so a new target,
a stop or an e-stop in mid-travel is exact. Position is a closed-form function of farm time, so
it is right at any clock speed and between any two looks at it; the motor keeps its last
``HISTORY`` profiles, so it is right for an instant before the latest command too (the simulated
world credits food by where the carriage was when it fell, which it learns after the fact).
The drive speaks the frames of devices/rail/can_frames.py through any frame port (a python-can
bus, or the slcan adapter on a pty). ESTOP latches: HOME and MOVE are refused IN_ESTOP until
CLEAR_FAULT (with the carriage at rest); each time the latch is set is kept in ``estops`` (farm
time, wall ``time.time()``) and written to the truth log as ``estop``.
"""
from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Iterable
from typing import Any

import can
from pydantic import BaseModel, ConfigDict, Field, model_validator

from devices.rail.can_frames import COMMAND_BASE, Command, Fault, Op, Reason, Reply, StatusFrame
from devices.sim.rail_motion import Profile, plan_move, plan_stop

log = logging.getLogger(__name__)

_AT = 5e-5            # m: "at" a position (half the 0.1 mm frame resolution)
_MOTION = ("homing", "moving")
HISTORY = 64          # profiles kept for looks into the past; the dispenser looks back at most
                      # to its previous look (run end, a read, 0.1 s of wall while refilling)


class SimRailParams(BaseModel):
    """farm.toml ``[sim.rail]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    rail_length_m: float = Field(22.0, gt=0, description="soft limit at the far end; home switch at 0")
    max_speed_m_s: float = Field(1.0, gt=0)
    accel_m_s2: float = Field(0.5, gt=0, description="acceleration and normal deceleration")
    homing_speed_m_s: float = Field(0.2, gt=0)
    estop_decel_m_s2: float = Field(5.0, gt=0, description="e-stop and drive faults brake this hard")
    start_m: float = Field(0.0, ge=0, description="where the carriage stands at power-on")
    heartbeat_s: float = Field(0.02, gt=0, description="status period, wall seconds")

    @model_validator(mode="after")
    def _start_on_rail(self):
        if self.start_m > self.rail_length_m:
            raise ValueError("start_m must lie on the rail (<= rail_length_m)")
        return self


class SimRailMotor:
    """The simulated motor controller with its carriage. All times are farm seconds from ``clock``.

    The physics answers at any instant (``position``, ``velocity``, ``report``, ``handle``); with a
    frame port (``start``) it also talks CAN: a status frame on every state change at once, after
    every accepted command, and every ``heartbeat_s`` wall seconds.
    """

    def __init__(self, params: SimRailParams, clock: Any, node_id: int = 1, truth=None):
        self.params = params
        self.truth = truth
        self.estops: list[tuple[float, float]] = []
        self.clock = clock
        self.node_id = node_id
        self._profiles: deque[Profile] = deque([Profile.rest(clock.now(), params.start_m)], maxlen=HISTORY)
        self._state = "unhomed"
        self._homed = False
        self._homing = False             # the profile under way ends on the home switch
        self._offset = params.start_m    # the encoder counts from wherever the carriage was at power-on
        self._fault = Fault.NONE
        self._target: float | None = None
        self._seq = 0
        self._silent = False
        self._port = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._beat: asyncio.Task | None = None

    # --- physics --------------------------------------------------------------------------------
    @property
    def _profile(self) -> Profile:
        return self._profiles[-1]

    @_profile.setter
    def _profile(self, profile: Profile) -> None:
        self._profiles.append(profile)       # the old one stays right for the time before

    def _profile_at(self, t: float) -> Profile:
        """The profile the carriage followed at ``t``: the latest planned at or before it."""
        profiles = tuple(self._profiles)     # a snapshot: the loop may plan a new one meanwhile
        return next((p for p in reversed(profiles) if p.start <= t), profiles[0])

    def position(self, t: float | None = None) -> float:
        """Where the carriage truly is on the rail (m from the home switch) at farm time ``t``."""
        t = self.clock.now() if t is None else t
        return self._profile_at(t).at(t)[0]

    def velocity(self, t: float | None = None) -> float:
        t = self.clock.now() if t is None else t
        return self._profile_at(t).at(t)[1]

    def travel(self, t_from: float, t_to: float, marks: Iterable[float] = ()) -> list[tuple[float, float, float]]:
        """The carriage's path over farm time [t_from, t_to] as pieces ``(t_a, t_b, position at
        the middle)``, cut wherever the motion changes and wherever the carriage passes one of
        the rail positions ``marks``: within a piece it stays on one side of every mark, so what
        happened over an interval (food falling, the hopper filling) splits exactly by place."""
        if t_to <= t_from:
            return []
        marks = sorted(set(marks))
        cuts = {t_from, t_to}
        cuts.update(c for prof in tuple(self._profiles) for c in [prof.start, *prof.cuts()] if t_from < c < t_to)
        cuts = sorted(cuts)
        edges = []
        for a, b in zip(cuts, cuts[1:], strict=False):
            # between two cuts the carriage goes one way: each mark between its ends is passed once
            pa, pb = self.position(a), self.position(b)
            lo, hi = min(pa, pb), max(pa, pb)
            edges.append(a)
            edges += [self._passes(a, b, m) for m in (marks if pa <= pb else marks[::-1]) if lo < m < hi]
        edges.append(t_to)
        return [(a, b, self.position((a + b) / 2)) for a, b in zip(edges, edges[1:], strict=False) if b > a]

    def _passes(self, a: float, b: float, mark: float) -> float:
        """When the carriage, going one way over [a, b], passes ``mark`` (bisection to a ulp)."""
        side = self.position(a) < mark
        while True:
            mid = (a + b) / 2
            if not a < mid < b:
                return b
            if (self.position(mid) < mark) == side:
                a = mid
            else:
                b = mid

    @property
    def state(self) -> str:
        self._settle(self.clock.now())
        return self._state

    def report(self, t: float | None = None) -> StatusFrame:
        """What the drive would say now: the encoder's view (offset until homed)."""
        t = self.clock.now() if t is None else t
        self._settle(t)
        p, v = self._profile_at(t).at(t)
        at_target = (self._state == "idle" and self._target is not None and abs(p - self._target) < _AT)
        at_limit = p < _AT or p > self.params.rail_length_m - _AT
        return StatusFrame(p - self._offset, v, self._state, self._homed, at_target, at_limit,
                           int(self._fault), self._seq)

    def handle(self, cmd: Command) -> Reason:
        """Apply a command at the current farm time; the reply's result."""
        t = self.clock.now()
        self._settle(t)
        reason = self._apply(cmd, t)
        if reason is Reason.ACCEPTED:
            self._seq = cmd.seq
            self._schedule()
        return reason

    def inject_fault(self, code: int = Fault.OVERCURRENT) -> None:
        """The drive trips: it brakes hard and latches the fault until CLEAR_FAULT."""
        t = self.clock.now()
        self._settle(t)
        p, v = self._profile.at(t)
        self._enter("fault", plan_stop(t, p, v, self.params.estop_decel_m_s2), code)

    def inject_stall(self) -> None:
        """Something blocks the carriage: it stops where it is, the drive reports STALL."""
        t = self.clock.now()
        self._settle(t)
        self._enter("fault", Profile.rest(t, self._profile.at(t)[0]), Fault.STALL)

    def press_estop(self) -> None:
        """The e-stop button on the drive's own panel: it brakes at the e-stop rate and latches
        until CLEAR_FAULT, as an ESTOP command does; nobody on the bus commanded it."""
        t = self.clock.now()
        self._settle(t)
        p, v = self._profile.at(t)
        if self._state != "estop":
            self._latched(t)
        self._enter("estop", plan_stop(t, p, v, self.params.estop_decel_m_s2), Fault.NONE)

    def silence(self) -> None:
        """The drive drops off the bus: no frames out, commands unheard. Motion goes on."""
        self._silent = True

    def resume(self) -> None:
        self._silent = False
        self._publish()

    def _apply(self, cmd: Command, t: float) -> Reason:
        p, v = self._profile.at(t)
        pr = self.params
        if cmd.op is Op.ESTOP:
            if self._state != "estop":
                self._latched(t)
            self._enter("estop", plan_stop(t, p, v, pr.estop_decel_m_s2), Fault.NONE)
        elif cmd.op is Op.STOP:
            if self._state in _MOTION:
                self._homing = False     # an interrupted homing leaves the drive unhomed
                self._profile = plan_stop(t, p, v, pr.accel_m_s2)
        elif cmd.op is Op.CLEAR_FAULT:
            if self._state in ("estop", "fault"):
                if v != 0:
                    return Reason.BUSY
                self._state, self._fault = ("idle" if self._homed else "unhomed"), Fault.NONE
        elif self._state in ("estop", "fault"):
            return Reason.IN_ESTOP if self._state == "estop" else Reason.IN_FAULT
        elif cmd.op is Op.HOME:
            self._homed, self._homing, self._target, self._state = False, True, 0.0, "homing"
            self._profile = plan_move(t, p, v, 0.0, pr.homing_speed_m_s, pr.accel_m_s2)
        elif not self._homed:
            return Reason.BUSY if self._state == "homing" else Reason.NOT_HOMED
        elif not 0.0 <= cmd.target_m <= pr.rail_length_m:
            return Reason.OUT_OF_RANGE
        else:
            speed = min(cmd.speed_m_s or pr.max_speed_m_s, pr.max_speed_m_s)
            self._target, self._state = cmd.target_m, "moving"
            self._profile = plan_move(t, p, v, cmd.target_m, speed, pr.accel_m_s2)
        self._settle(t)                  # a move to where it stands is over at once
        return Reason.ACCEPTED

    def _latched(self, t: float) -> None:
        wall = time.time()
        self.estops.append((t, wall))
        if self.truth is not None:
            self.truth.write("estop", t, device="rail", wall=wall)

    def _enter(self, state: str, profile: Profile, fault: int) -> None:
        self._state, self._profile, self._fault, self._homing = state, profile, Fault(fault), False
        self._publish()
        self._schedule()

    def _settle(self, t: float) -> bool:
        """End a homing or a move whose profile is over by ``t``; True when the state changed."""
        if self._state not in _MOTION or t < self._profile.t_end:
            return False
        if self._homing:
            self._homed, self._homing, self._offset = True, False, 0.0   # the switch zeroes the encoder
        self._state = "idle" if self._homed else "unhomed"
        self._publish()
        return True

    # --- CAN ------------------------------------------------------------------------------------
    async def start(self, port) -> None:
        """Talk through ``port`` (``start(receive)``, ``send(msg)``, ``stop()``): see slcan_adapter."""
        self._loop = asyncio.get_running_loop()
        await port.start(self._on_message)
        self._port = port
        self._beat = asyncio.create_task(self._heartbeat(), name=f"rail node {self.node_id} heartbeat")
        self._schedule()

    async def stop(self) -> None:
        port, self._port = self._port, None
        if self._timer is not None:
            self._timer.cancel()
        if self._beat is not None:
            self._beat.cancel()
            await asyncio.gather(self._beat, return_exceptions=True)
            self._beat = None
        if port is not None:
            await port.stop()

    def _on_message(self, msg: can.Message) -> None:
        if msg.arbitration_id != COMMAND_BASE + self.node_id or self._silent or msg.is_remote_frame:
            return
        try:
            cmd = Command.from_bytes(msg.data)
        except ValueError:
            data = bytes(msg.data) + b"\0\0"
            self._send(Reply(data[1], data[0], Reason.BAD_COMMAND))
            return
        reason = self.handle(cmd)
        if reason is Reason.ACCEPTED:
            self._publish()              # status first (carries seq), so the driver sees the effect
        self._send(Reply(cmd.seq, cmd.op, reason))

    def _publish(self) -> None:
        if self._port is not None and not self._silent:
            self._send(self.report())

    def _send(self, frame) -> None:
        if self._port is None or self._silent:
            return
        try:
            self._port.send(frame.to_message(self.node_id))
        except (can.CanError, OSError) as exc:   # a drive on a dead bus keeps running
            log.debug("rail node %d: frame lost: %s", self.node_id, exc)

    async def _heartbeat(self) -> None:
        while True:
            if not self._settle(self.clock.now()):
                self._publish()
            await asyncio.sleep(self.params.heartbeat_s)

    def _schedule(self) -> None:
        """Wake at the wall instant the motion ends, to report it at once. A ManualClock
        (wall() == 0) has no such instant: its end is seen by the next heartbeat."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._loop is None or self._state not in _MOTION:
            return
        wall = self.clock.wall(self._profile.t_end - self.clock.now())
        if wall > 0:
            self._timer = self._loop.call_later(wall, self._on_timer)

    def _on_timer(self) -> None:
        self._timer = None
        if not self._settle(self.clock.now()):
            self._schedule()             # woke a hair early
