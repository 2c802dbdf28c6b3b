"""The simulated contact hub: the tanks' contacts as the hub's serial lines, on a pseudo-terminal.

The controller opens ``hub.port`` (the pty's slave path) with the real ``serial`` driver
(devices/contacts/serial_hub.py, whose docstring has the line protocol). Every ``period_s`` of
wall time an asyncio task pulls ``contacts_until(clock.now())`` from each ``SimTank``, writes one
line per contact, in time order across tanks, and a heartbeat. The line protocol promises a
heartbeat at least once a *farm* second, so by default one goes out at the first poll after
``heartbeat_farm_s`` (half a farm second) of farm time, or ``heartbeat_s`` (0.25 s) of wall
time, whichever comes first: at 1x that is every 0.25 s, at 1440x every poll (the poll period
is the floor), and under a ManualClock at the first poll after the test moves time (the wall
rule keeps a frozen clock's line alive). An explicit ``heartbeat_s`` is the only rule. Writes are
batched and non-blocking: when the pty is full (no reader, or a reader too slow) whole lines are
dropped and counted in ``dropped``; their sequence numbers are spent anyway, as a real hub's
are, so the reader sees the loss. ``noise_per_s`` injects corrupt lines (bad checksum, torn
or garbage bytes) to exercise the reader's rejection of line noise.

The sim keeps its own handle on the slave open, so writes never fail with EIO while no reader
is attached; ``stop()`` closes both ends, and a reader then sees the port vanish.
"""
from __future__ import annotations

import asyncio
import heapq
import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from devices.contacts.serial_hub import contact_line, heartbeat_line
from devices.sections import validate_section
from devices.sim.ptys import close_pty, end_task, open_pty, write_lines

MAX_PENDING = 1 << 16                   # bytes kept for a partial write before dropping lines
HEARTBEAT_S = 0.25                      # wall: keeps the line alive whatever the farm clock does
HEARTBEAT_FARM_S = 0.5                  # farm: beats land within a farm second despite poll jitter


class SimHubParams(BaseModel):
    """farm.toml ``[sim.contacts]``. Wall-clock seconds: they are properties of the line."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    period_s: float | None = Field(None, gt=0, le=1, description="how often the tanks are polled; "
                                   "default: 5 ms, shorter in fast simulation (a real hub sends at once)")
    heartbeat_s: float | None = Field(None, gt=0, le=10, description="wall seconds between heartbeats; "
                                      "default: 0.25 s, and every half farm second in fast simulation")
    noise_per_s: float = Field(0.0, ge=0, description="corrupt lines injected per second")
    seed: int = 0


class SimContactHub:
    """``tanks``: objects with ``contacts_until(t) -> [(t, sensor)]`` (``SimTank``, ``Replay``)."""

    def __init__(self, tanks, clock, params: SimHubParams | dict | None = None, truth=None, *,
                 where: str = "farm.toml"):
        if not isinstance(params, SimHubParams):
            params = validate_section(SimHubParams, params or {}, where, "sim.contacts")
        self.tanks = list(tanks)
        self.clock = clock
        self.truth = truth
        # a real hub sends each contact at once; the twin polls, so keep its lag under ~1 farm
        # second where the wall allows (at 2880x that is the 1 ms floor)
        default = min(0.005, max(0.001, 1.0 / getattr(clock, "speed", 1.0)))
        self.period_s = params.period_s if params.period_s is not None else default
        explicit = params.heartbeat_s is not None
        self.heartbeat_s = params.heartbeat_s if explicit else HEARTBEAT_S
        self.heartbeat_farm_s = None if explicit else HEARTBEAT_FARM_S
        self.noise_per_s = params.noise_per_s
        self.rng = np.random.default_rng(params.seed)
        self.sent = self.dropped = self.noise = 0
        self.seq = 0
        self._master = self._slave = -1
        self._port = ""
        self._pending = b""
        self._task: asyncio.Task | None = None

    @property
    def port(self) -> str:
        return self._port

    async def start(self) -> None:
        self._master, self._slave, self._port = open_pty()
        self._task = asyncio.create_task(self._serve(), name="sim-contact-hub")

    async def stop(self) -> None:
        await end_task(self._task)
        self._task = None
        close_pty(self._master, self._slave)
        self._master = self._slave = -1

    async def _serve(self) -> None:
        loop = asyncio.get_running_loop()
        next_beat = next_farm_beat = -math.inf
        farm_s = self.heartbeat_farm_s
        while True:
            now = self.clock.now()
            contacts = list(self._contacts(now))
            beat = loop.time() >= next_beat or now >= next_farm_beat
            # noise rides on traffic, ahead of it: every corrupt line is followed by a valid one
            lines = self._noise() if contacts or beat else []
            lines += [contact_line(self._next_seq(), sensor, t) for t, sensor in contacts]
            if beat:
                lines.append(heartbeat_line(self._next_seq(), now))
                next_beat = loop.time() + self.heartbeat_s
                next_farm_beat = math.inf if farm_s is None else now + farm_s
            self._write(lines)
            await asyncio.sleep(self.period_s)

    def _contacts(self, now: float):
        per_tank = [tank.contacts_until(now) for tank in self.tanks]
        return heapq.merge(*per_tank) if len(per_tank) > 1 else per_tank[0] if per_tank else []

    def _next_seq(self) -> int:
        seq, self.seq = self.seq, (self.seq + 1) % 65536
        return seq

    def _noise(self) -> list[bytes]:
        n = self.rng.poisson(self.noise_per_s * self.period_s) if self.noise_per_s else 0
        out = []
        for _ in range(n):
            kind = self.rng.integers(3)
            line = contact_line(self._next_seq(), "T1-a", self.clock.now())
            if kind == 0:                       # a flipped bit: the checksum no longer matches
                i = int(self.rng.integers(1, line.index(b"*")))
                line = line[:i] + bytes([line[i] ^ 0x04]) + line[i + 1:]
            elif kind == 1:                     # torn: the tail lost
                line = line[: int(self.rng.integers(2, len(line) - 3))] + b"\r\n"
            else:                               # garbage bytes
                line = bytes(self.rng.integers(32, 127, 20, dtype=np.uint8)) + b"\r\n"
            out.append(line)
        self.noise += n
        return out

    def _write(self, lines: list[bytes]) -> None:
        self._pending, dropped = write_lines(self._master, self._pending, lines, MAX_PENDING)
        self.dropped += dropped
        self.sent += len(lines) - dropped
