"""Where an elastic clock's wall time goes: a thread samples the clock file every ``period_s`` of
wall and adds each interval's wall and farm seconds to the reason the clock ran at that speed then
(``fast``, or the busy slots' words: ``sim:fish asking``, ``controller:surveying``...). The samples
(wall, farm, speed) are kept: a run's evidence maps wall instants (the machine's stalls) to farm
time through them and asks what speed the clock had at a farm instant."""
from __future__ import annotations

import bisect
import threading
import time
from collections import defaultdict

from devices.elastic_clock import BUSY, ElasticClock, Segment


class ClockWatch:
    def __init__(self, clock: ElasticClock, period_s: float = 0.01):
        self.clock, self.period_s = clock, period_s
        self.wall = defaultdict(float)
        self.farm = defaultdict(float)
        self.samples: list[tuple[float, float, float]] = []      # (wall, farm, speed)
        self.segments: list[Segment] = []                          # each segment seen, in order
        self._last: tuple[float, float, str] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="clock-watch", daemon=True)

    def start(self) -> ClockWatch:
        self._thread.start()
        return self

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join(timeout=5)
        return self.summary()

    def reason(self) -> str:
        if self.clock.speed >= self.clock.fast:
            return "fast"
        busy = sorted(f"{s.name}:{s.why}" for s in self.clock.slots() if s.kind == BUSY)
        return " + ".join(busy) if busy else "slow (at the lookahead limit)"

    def _run(self) -> None:
        self.sample()
        while not self._stop.wait(self.period_s):
            self.sample()

    def sample(self, wall: float | None = None) -> None:
        """One look at the clock (the thread's; a test may look itself, at a wall instant it sets)."""
        w1, f1 = time.time() if wall is None else wall, self.clock.now()
        self.samples.append((w1, f1, self.clock.speed))
        self._note_segment()
        if self._last is not None:
            w0, f0, why = self._last
            self.wall[why] += w1 - w0
            self.farm[why] += f1 - f0
        self._last = (w1, f1, self.reason())

    def _note_segment(self) -> None:
        seg = self.clock.segment()
        if not self.segments or seg != self.segments[-1]:
            self.segments.append(seg)

    def speed_at(self, farm_t: float) -> float | None:
        """The clock's speed at farm instant ``farm_t`` by the newest segment seen anchored at or before
        it (each segment starts at the farm time of its writing; None: none seen yet). A segment that
        lived less than ``period_s`` of wall is never seen, so this may be an older one's word."""
        i = bisect.bisect_right(self.segments, farm_t, key=lambda g: g.farm0)
        return self.segments[i - 1].speed_at(farm_t) if i else None

    def ran_fast_at(self, farm_t: float) -> bool:
        """Whether the clock ran fast through farm instant ``farm_t``: the segment seen in force then
        and the first sample after it both say so. Either alone misreads (2026-12-03, the 60-day
        grow-out): the next sample comes up to ``period_s`` of wall later, 6 farm s at 600x, after a
        fish episode's demand turned down a second after its start has let the clock speed up again;
        a segment the simulator wrote in the last ``period_s`` before an episode (its lookahead moved
        to the start) is unseen, so the segment seen is an older, faster one."""
        fast = self.clock.fast
        return (self.speed_at(farm_t) or 0.0) >= fast and (self.speed_after(farm_t) or 0.0) >= fast

    def speed_after(self, farm_t: float) -> float | None:
        """The speed of the first sample at or after farm instant ``farm_t`` (None: none yet)."""
        i = bisect.bisect_left(self.samples, farm_t, key=lambda s: s[1])
        return self.samples[i][2] if i < len(self.samples) else None

    def farm_at(self, wall: float) -> float:
        """Farm time at a wall instant of the run, between the samples around it."""
        i = bisect.bisect_left(self.samples, wall, key=lambda s: s[0])
        if i == 0:
            return self.samples[0][1]
        if i == len(self.samples):
            return self.samples[-1][1]
        (w0, f0, _), (w1, f1, _) = self.samples[i - 1], self.samples[i]
        return f0 + (f1 - f0) * (wall - w0) / (w1 - w0) if w1 > w0 else f0

    def summary(self) -> dict:
        return {k: {"wall_s": round(self.wall[k], 1), "farm_h": round(self.farm[k] / 3600.0, 2)}
                for k in sorted(self.wall, key=self.wall.get, reverse=True)}
