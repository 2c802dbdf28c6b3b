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

    def at(self, wall: float) -> float:
        """Farm time at wall instant ``wall`` (a log record's)."""
        return self.epoch_farm + (wall - self.epoch_wall) * self.speed

    def wall(self, farm_seconds: float) -> float:
        """Wall seconds that ``farm_seconds`` of farm time take."""
        return farm_seconds / self.speed

    def wall_since(self, farm_t: float) -> float:
        """Wall seconds since farm time ``farm_t`` was now (0 if it is yet to come)."""
        return max(0.0, self.now() - farm_t) / self.speed

    def sleep(self, farm_seconds: float) -> None:
        if farm_seconds > 0:
            time.sleep(farm_seconds / self.speed)

    async def asleep(self, farm_seconds: float) -> None:
        await asyncio.sleep(max(0.0, farm_seconds) / self.speed)

    def iso(self, t: float | None = None) -> str:
        return iso(self.now() if t is None else t)

    def as_args(self) -> list[str]:
        """Command-line flags that hand this timeline to a child process. The wall clock itself
        (speed 1, farm time = wall time: ``real()``'s epochs of 0, 1970) goes as ``--speed 1``
        alone: epochs are held to the farm's years."""
        if self.speed == 1.0 and self.epoch_wall == self.epoch_farm:
            return ["--speed", "1.0"]
        return ["--speed", repr(self.speed), "--epoch-wall", repr(self.epoch_wall),
                "--epoch-farm", repr(self.epoch_farm)]


@dataclass
class ManualClock:
    """A clock that moves only when a test advances it. Sleepers wake when their time comes.

    ``asyncio`` sleepers park on a future of their own loop; moving the clock (``advance()`` or
    assigning ``t``, from any thread) resolves the due ones through ``call_soon_threadsafe``, so
    an idle sleeper costs nothing.
    """

    t: float = 1_780_000_000.0  # 2026-05-28, an arbitrary farm morning
    speed: float = float("inf")
    _cond: threading.Condition = field(default_factory=threading.Condition, repr=False)
    _sleepers: list[tuple[float, asyncio.AbstractEventLoop, asyncio.Future]] = field(
        default_factory=list, repr=False)

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)
        if name == "t" and "_sleepers" in self.__dict__:
            self._wake_due()

    def now(self) -> float:
        return self.t

    def wall(self, farm_seconds: float) -> float:
        return 0.0

    def wall_since(self, farm_t: float) -> float:
        return 0.0

    def advance(self, seconds: float) -> None:
        with self._cond:
            self.t += seconds

    def sleep(self, farm_seconds: float) -> None:
        with self._cond:
            until = self.t + farm_seconds
            while self.t < until:
                self._cond.wait(0.05)

    async def asleep(self, farm_seconds: float) -> None:
        loop = asyncio.get_running_loop()
        with self._cond:
            until = self.t + farm_seconds
            if self.t >= until:
                return
            sleeper = (until, loop, loop.create_future())
            self._sleepers.append(sleeper)
        try:
            await sleeper[2]
        finally:
            with self._cond:
                if sleeper in self._sleepers:
                    self._sleepers.remove(sleeper)

    def _wake_due(self) -> None:
        with self._cond:
            self._cond.notify_all()
            due = [s for s in self._sleepers if s[0] <= self.t]
            self._sleepers[:] = [s for s in self._sleepers if s[0] > self.t]
        for _until, loop, future in due:
            try:
                loop.call_soon_threadsafe(_resolve, future)
            except RuntimeError:        # that loop is closed: its sleeper is gone with it
                pass

    def iso(self, t: float | None = None) -> str:
        return iso(self.now() if t is None else t)


def _resolve(future: asyncio.Future) -> None:
    if not future.done():
        future.set_result(None)


def iso(t: float) -> str:
    """Farm time as ISO 8601 UTC with milliseconds."""
    return dt.datetime.fromtimestamp(t, dt.UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def farm_date(t: float, utc_offset_h: float = 0.0) -> str:
    """The farm's calendar day (YYYY-MM-DD) at farm time ``t``; rations reset at local midnight.
    (``time.gmtime``, not datetime: a report's --since at the last second of 9999, an hour ahead of
    UTC, is a day of the year 10000, which datetime refuses.)"""
    return time.strftime("%Y-%m-%d", time.gmtime(t + utc_offset_h * 3600.0))
