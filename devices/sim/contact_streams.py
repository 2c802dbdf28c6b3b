"""Labelled contact streams for every case of DESIGN.md's contact sensor model.

Pure functions of a numpy ``Generator``: the demand filter's tests and benchmark feed on them,
and ``SimTank`` (devices/sim/fish.py) draws its turbulence and faults from the same functions,
so the simulator and the tests speak about the same physics.

- fish demand:  sustained contacts at 0.1–2 /s for 1–10 min, Poisson, regular (a jittered beat)
                or paced (jittered intervals);
- turbulence:   sparse Poisson contacts below 0.05 /s, and chatter bursts of 3–20 /s for < 10 s;
- faults:       a stuck sensor (a fixed high rate, for minutes) and a dead one (silent for minutes).

A ``Stream`` keeps the contacts (sorted by time) and the ground truth that made them.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FISH, TURBULENCE, BURST, STUCK = 0, 1, 2, 3


@dataclass(frozen=True)
class Episode:
    tank: str
    start: float
    end: float
    rate_hz: float
    pattern: str = "poisson"


@dataclass(frozen=True)
class Burst:
    tank: str
    sensor: str
    start: float
    duration_s: float
    rate_hz: float


@dataclass(frozen=True)
class Fault:
    tank: str
    sensor: str
    start: float
    end: float
    kind: str          # "stuck" | "dead"


@dataclass
class Stream:
    t: np.ndarray                         # float64, sorted
    tank: np.ndarray                      # str
    sensor: np.ndarray                    # str
    source: np.ndarray                    # int8: FISH, TURBULENCE, BURST, STUCK
    episodes: list[Episode] = field(default_factory=list)
    bursts: list[Burst] = field(default_factory=list)
    faults: list[Fault] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.t)

    def rows(self):
        """(t, tank, sensor) tuples in time order, as the filter takes them."""
        return zip(self.t.tolist(), self.tank.tolist(), self.sensor.tolist(), strict=True)

    def write_csv(self, path: str | Path) -> None:
        """CONTACTS.csv of the ``fishfarm demand`` contract: ``t_s,tank,sensor``, sorted."""
        with open(path, "w", newline="", encoding="utf-8") as fh:
            out = csv.writer(fh, lineterminator="\n")
            out.writerow(("t_s", "tank", "sensor"))
            out.writerows((f"{t:.3f}", k, s) for t, k, s in self.rows())


def empty() -> Stream:
    return Stream(np.empty(0), np.empty(0, dtype=object), np.empty(0, dtype=object), np.empty(0, np.int8))


def merge(*streams: Stream) -> Stream:
    """One stream of all contacts in time order (stable: equal times keep their input order)."""
    parts = [s for s in streams if s is not None]
    t = np.concatenate([s.t for s in parts]) if parts else np.empty(0)
    order = np.argsort(t, kind="stable")
    cat = lambda name, dtype: np.concatenate([getattr(s, name) for s in parts]).astype(dtype)[order]  # noqa: E731
    return Stream(t[order], cat("tank", object), cat("sensor", object), cat("source", np.int8),
                  [e for s in parts for e in s.episodes], [b for s in parts for b in s.bursts],
                  [f for s in parts for f in s.faults])


def _labelled(t: np.ndarray, tank: str, sensors, rng: np.random.Generator, source: int) -> Stream:
    names = np.asarray(list(sensors), dtype=object)
    who = names[rng.integers(0, len(names), size=len(t))] if len(names) > 1 else np.full(len(t), names[0])
    return Stream(t, np.full(len(t), tank, dtype=object), who.astype(object),
                  np.full(len(t), source, dtype=np.int8))


def poisson_times(rng: np.random.Generator, rate_hz: float, t0: float, t1: float) -> np.ndarray:
    """A homogeneous Poisson process on [t0, t1): the count is Poisson, the times uniform."""
    if rate_hz <= 0 or t1 <= t0:
        return np.empty(0)
    n = rng.poisson(rate_hz * (t1 - t0))
    return np.sort(rng.uniform(t0, t1, n))


def regular_times(rng: np.random.Generator, rate_hz: float, t0: float, t1: float,
                  jitter: float = 0.1) -> np.ndarray:
    """Contacts every 1/rate with a random phase, each moved by up to ±jitter of the period."""
    period = 1.0 / rate_hz
    t = t0 + rng.uniform(0, period) + period * np.arange(int((t1 - t0) * rate_hz) + 1)
    t = t + rng.uniform(-jitter, jitter, len(t)) * period
    return np.sort(t[(t >= t0) & (t < t1)])


def paced_times(rng: np.random.Generator, rate_hz: float, t0: float, t1: float,
                jitter: float = 0.1) -> np.ndarray:
    """Contacts at a steady pace: each interval is 1/rate ± up to ``jitter`` of it (a renewal
    process; unlike ``regular_times`` the phase wanders), the first at a random phase."""
    period = 1.0 / rate_hz
    n = int((t1 - t0) * rate_hz / (1.0 - jitter)) + 2
    gaps = period * (1.0 + rng.uniform(-jitter, jitter, n))
    t = t0 + rng.uniform(0, period) + np.concatenate(([0.0], np.cumsum(gaps[:-1])))
    return t[t < t1]


PATTERNS = {"regular": regular_times, "paced": paced_times}


def fish_demand(rng, tank: str, sensors, start: float, duration_s: float, rate_hz: float,
                pattern: str = "poisson", jitter: float = 0.1) -> Stream:
    """Hungry fish bumping the tank's sensors at ``rate_hz`` (whole tank) for ``duration_s``:
    "poisson", "regular" (a strict beat, each contact moved by up to ±jitter of the period) or
    "paced" (each interval the period ±jitter)."""
    end = start + duration_s
    if pattern == "poisson":
        t = poisson_times(rng, rate_hz, start, end)
    else:
        t = PATTERNS[pattern](rng, rate_hz, start, end, jitter)
    s = _labelled(t, tank, sensors, rng, FISH)
    s.episodes.append(Episode(tank, start, end, rate_hz, pattern))
    return s


def turbulence(rng, tank: str, sensors, t0: float, t1: float, rate_hz: float) -> Stream:
    """Sparse random contacts (waves, currents) at ``rate_hz`` for the whole tank."""
    return _labelled(poisson_times(rng, rate_hz, t0, t1), tank, sensors, rng, TURBULENCE)


def chatter_bursts(rng, tank: str, sensors, t0: float, t1: float, per_hour: float,
                   rate_hz=(3.0, 20.0), duration_s=(0.3, 9.9)) -> Stream:
    """Bursts from pumps or aeration: each on one sensor, Poisson at 3–20 /s for under 10 s."""
    starts = poisson_times(rng, per_hour / 3600.0, t0, t1)
    parts, log = [], []
    for start in starts.tolist():
        sensor = list(sensors)[rng.integers(0, len(sensors))]
        rate, dur = rng.uniform(*rate_hz), rng.uniform(*duration_s)
        t = poisson_times(rng, rate, start, start + dur)
        parts.append(_labelled(t, tank, [sensor], rng, BURST))
        log.append(Burst(tank, sensor, start, dur, rate))
    out = merge(*parts) if parts else empty()
    out.bursts = log
    return out


def stuck_sensor(rng, tank: str, sensor: str, start: float, end: float, rate_hz: float = 5.0,
                 pattern: str = "regular") -> Stream:
    """A sensor whose switch chatters on its own at a fixed high rate from ``start`` to ``end``."""
    t = regular_times(rng, rate_hz, start, end, jitter=0.02) if pattern == "regular" else \
        poisson_times(rng, rate_hz, start, end)
    s = _labelled(t, tank, [sensor], rng, STUCK)
    s.faults.append(Fault(tank, sensor, start, end, "stuck"))
    return s


def kill_sensor(stream: Stream, tank: str, sensor: str, start: float, end: float) -> Stream:
    """The same stream with ``sensor`` silent on [start, end): a dead sensor or a cut cable."""
    dead = (stream.tank == tank) & (stream.sensor == sensor) & (stream.t >= start) & (stream.t < end)
    keep = ~dead
    return Stream(stream.t[keep], stream.tank[keep], stream.sensor[keep], stream.source[keep],
                  list(stream.episodes), list(stream.bursts),
                  [*stream.faults, Fault(tank, sensor, start, end, "dead")])


def episode_starts(rng, t0: float, t1: float, per_day: float, gap_s: float = 1200.0,
                   max_duration_s: float = 600.0) -> list[float]:
    """Episode start times: hunger returns some while after the last meal, never overlapping."""
    starts, t = [], t0 + rng.exponential(86400.0 / per_day)
    while t + max_duration_s < t1:
        starts.append(t)
        t += max_duration_s + gap_s + rng.exponential(86400.0 / per_day)
    return starts


def tank_day(rng: np.random.Generator, tank: str = "T1", sensors=("T1-a", "T1-b"), t0: float = 0.0,
             days: float = 1.0, *, episodes_per_day: float = 8.0, rate_hz=(0.1, 2.0),
             duration_s=(60.0, 600.0), pattern: str = "poisson", turbulence_hz: float = 0.05,
             bursts_per_hour: float = 4.0, jitter: float = 0.1) -> Stream:
    """A tank over ``days``: fish-demand episodes (rates log-uniform in ``rate_hz``), turbulence
    all day long, chatter bursts. ``pattern``: "poisson", "regular", "paced" or "mixed" (poisson
    or regular); ``jitter`` for the regular and paced ones."""
    t1 = t0 + days * 86400.0
    parts = [turbulence(rng, tank, sensors, t0, t1, turbulence_hz),
             chatter_bursts(rng, tank, sensors, t0, t1, bursts_per_hour)]
    lo, hi = np.log(rate_hz[0]), np.log(rate_hz[1])
    for start in episode_starts(rng, t0, t1, episodes_per_day, max_duration_s=duration_s[1]):
        kind = pattern if pattern != "mixed" else ("poisson", "regular")[rng.integers(0, 2)]
        parts.append(fish_demand(rng, tank, sensors, start, rng.uniform(*duration_s),
                                 float(np.exp(rng.uniform(lo, hi))), kind, jitter))
    return merge(*parts)


class Replay:
    """A recorded stream played back in farm time: ``contacts_until(t)`` like a ``SimTank``."""

    def __init__(self, stream: Stream):
        self.stream = stream
        self._i = 0

    def contacts_until(self, t: float) -> list[tuple[float, str]]:
        j = int(np.searchsorted(self.stream.t, t, side="left"))
        s = self.stream
        out = list(zip(s.t[self._i:j].tolist(), s.sensor[self._i:j].tolist(), strict=True))
        self._i = max(self._i, j)
        return out
