"""The one clock every component reads.

Farm time is Unix seconds. On a farm it is the wall clock; in simulation it runs
``speed`` times faster than the wall from a shared epoch, so separate processes
(the controller, the simulated farm) that are given the same epoch and speed agree
on farm time without talking to each other, and a restarted controller rejoins the
same timeline.

Physics and feeding logic count in farm seconds. Communication timeouts (a serial
line gone quiet, a Modbus reply) are properties of the link, not of the farm, and
are counted in wall seconds: ``clock.wall(dt)`` converts.
"""
from __future__ import annotations

import asyncio
import datetime as dt
import threading
import time
from dataclasses import dataclass, field


@dataclass(frozen=True)
class ScaledClock:
    """farm_now = epoch_farm + (time.time() - epoch_wall) * speed."""

    speed: float = 1.0
    epoch_wall: float = 0.0
    epoch_farm: float = 0.0

    @classmethod
    def real(cls) -> ScaledClock:
        return cls(1.0, 0.0, 0.0)

    @classmethod
    def starting(cls, speed: float, farm_start: float | None = None) -> ScaledClock:
        """A clock whose farm time is ``farm_start`` (default: now) at this instant."""
        wall = time.time()
        return cls(float(speed), wall, wall if farm_start is None else float(farm_start))

    def now(self) -> float:
        return self.epoch_farm + (time.time() - self.epoch_wall) * self.speed

    def wall(self, farm_seconds: float) -> float:
        """Wall seconds that ``farm_seconds`` of farm time take."""
        return farm_seconds / self.speed

    def sleep(self, farm_seconds: float) -> None:
        if farm_seconds > 0:
            time.sleep(farm_seconds / self.speed)

    async def asleep(self, farm_seconds: float) -> None:
        await asyncio.sleep(max(0.0, farm_seconds) / self.speed)

    def iso(self, t: float | None = None) -> str:
        return iso(self.now() if t is None else t)

    def as_args(self) -> list[str]:
        """Command-line flags that hand this timeline to a child process."""
        return ["--speed", repr(self.speed), "--epoch-wall", repr(self.epoch_wall),
                "--epoch-farm", repr(self.epoch_farm)]


@dataclass
class ManualClock:
    """A clock that moves only when a test advances it. Sleepers wake when their time comes."""

    t: float = 1_780_000_000.0  # 2026-05-28, an arbitrary farm morning
    speed: float = float("inf")
    _cond: threading.Condition = field(default_factory=threading.Condition, repr=False)

    def now(self) -> float:
        return self.t

    def wall(self, farm_seconds: float) -> float:
        return 0.0

    def advance(self, seconds: float) -> None:
        with self._cond:
            self.t += seconds
            self._cond.notify_all()

    def sleep(self, farm_seconds: float) -> None:
        until = self.t + farm_seconds
        with self._cond:
            while self.t < until:
                self._cond.wait(0.05)

    async def asleep(self, farm_seconds: float) -> None:
        until = self.t + farm_seconds
        while self.t < until:
            await asyncio.sleep(0.0005)

    def iso(self, t: float | None = None) -> str:
        return iso(self.now() if t is None else t)


def iso(t: float) -> str:
    """Farm time as ISO 8601 UTC with milliseconds."""
    return dt.datetime.fromtimestamp(t, dt.UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def farm_date(t: float, utc_offset_h: float = 0.0) -> str:
    """The farm's calendar day (YYYY-MM-DD) at farm time ``t``; rations reset at local midnight."""
    return dt.datetime.fromtimestamp(t + utc_offset_h * 3600.0, dt.UTC).date().isoformat()
