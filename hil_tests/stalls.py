"""A witness of the machine's stalls: spans of wall time in which none of our processes ran.

This VM is at times descheduled as a whole for up to about a second. At 360x that is six farm
minutes in which the controller could do nothing, nor could the simulated devices: a demand
served late across such a span says nothing about the controller. A thread of the test process
wakes every ``period_s`` and records every gap longer than ``threshold_s`` between its wake-ups —
far longer than a busy machine delays a sleeper (a few ms at the CI's load of 2), so only a
machine that stopped is recorded. A controller that blocks its own loop leaves no gap here: that
lateness stays the controller's.
"""
from __future__ import annotations

import threading
import time


class StallWitness:
    def __init__(self, threshold_s: float = 0.25, period_s: float = 0.005):
        self.threshold_s, self.period_s = threshold_s, period_s
        self.spans: list[tuple[float, float]] = []          # wall (time.time()) spans
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="stall-witness", daemon=True)

    def start(self) -> StallWitness:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _watch(self) -> None:
        last_mono, last_wall = time.monotonic(), time.time()
        while not self._stop.wait(self.period_s):
            mono, wall = time.monotonic(), time.time()
            if mono - last_mono > self.threshold_s:
                self.spans.append((last_wall, wall))
            last_mono, last_wall = mono, wall

    def farm_spans(self, epoch_wall: float, epoch_farm: float, speed: float) -> list[tuple[float, float]]:
        """The stalls in farm time, on a timeline ``farm = epoch_farm + (wall - epoch_wall) x speed``."""
        return [(epoch_farm + (a - epoch_wall) * speed, epoch_farm + (b - epoch_wall) * speed)
                for a, b in self.spans]


def stalled_s(spans: list[tuple[float, float]], t0: float, t1: float) -> float:
    """Farm seconds of [t0, t1] that fell in a stall."""
    return sum(max(0.0, min(b, t1) - max(a, t0)) for a, b in spans)
