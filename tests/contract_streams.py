"""Contact streams written from DESIGN.md's contact sensor model alone, independently of the
filter (controller/demand.py) and of the simulator's generator (devices/sim/contact_streams.py):
numpy only, nothing imported from the project.

The contract's words, and how each is drawn here:
- *fish demand: sustained contacts at 0.1–2 /s for 1–10 minutes.* An episode has a peak rate;
  its rate ramps linearly from 0 to the peak over ``ramp_s``, holds, and ramps down again. Fish
  contacts are an inhomogeneous Poisson process (thinning), or, ``paced``, intervals drawn from a
  gamma law (shape 4: a steadier pace than Poisson) at the current rate. Each contact lands on
  one of the tank's sensors with unequal weights (split sensors).
- *turbulence: sparse random contacts (below 0.05 /s on average)*: Poisson at the tank's own
  background (here <= 0.02 /s, what the farm's tanks show), on random sensors.
- *or chatter bursts (3–20 contacts/s for under 10 s) from waves, pumps or aeration*: a burst is
  Poisson at 3–20 /s for 0.3–9.9 s on one sensor (sometimes two). Bursts come on their own, just
  before an episode's first contact, or as a *wave*: one event hitting several tanks within
  seconds of each other.
  Sparse random contacts need not come one at a time: ``clustered_background`` draws them as
  wave hits, each touching one sensor 1–3 times a second or a few apart (the average still below
  0.05 /s), an outside tester's reading of the same words.
- *stuck sensor: contacts at a fixed high rate for minutes*: 3–10 /s, each contact jittered by a
  few % of the period; *dead sensor: none at all while the tank's other sensors fire*: its
  contacts are removed for the span.

A case is scored by ``score`` from the events a filter returns: recall within 60 s of each
episode's FIRST contact (every episode listed, not averaged away), latency, demands outside any
episode per tank-day, faults found.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

DAY = 86400.0
AFTERGLOW_S = 10.0
FISH, TURB, BURST, STUCK = 0, 1, 2, 3


@dataclass
class Episode:
    tank: str
    start: float            # the rate starts ramping up
    end: float              # the rate is back at 0
    peak_hz: float
    first: float = math.nan  # the first fish contact (the 60 s run from here)


@dataclass
class Fault:
    tank: str
    sensor: str
    kind: str               # "stuck" | "dead"
    start: float
    end: float


@dataclass
class Farm:
    """A generated stream: contacts sorted by time, and the truth behind them."""
    t: np.ndarray
    tank: np.ndarray
    sensor: np.ndarray
    source: np.ndarray
    episodes: list[Episode] = field(default_factory=list)
    faults: list[Fault] = field(default_factory=list)
    tank_days: float = 0.0
    background_hz: dict[str, float] = field(default_factory=dict)

    def rows(self):
        return zip(self.t.tolist(), self.tank.tolist(), self.sensor.tolist(), strict=True)

    def __len__(self) -> int:
        return len(self.t)


class Builder:
    """Collects contacts tank by tank, then sorts them into a ``Farm``."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)
        self.parts: list[tuple[np.ndarray, str, np.ndarray, int]] = []
        self.episodes: list[Episode] = []
        self.faults: list[Fault] = []
        self.background_hz: dict[str, float] = {}
        self.weights: dict[str, np.ndarray] = {}

    def add(self, t, tank: str, sensors, source: int) -> None:
        t = np.asarray(t, dtype=float)
        if len(t):
            s = np.asarray(sensors, dtype=object)
            self.parts.append((t, tank, s if s.shape else np.full(len(t), sensors, dtype=object), source))

    # -- the contract's parts -----------------------------------------------------------------
    def background(self, tank, sensors, a, b, hz) -> None:
        self.background_hz[tank] = hz
        n = self.rng.poisson(hz * (b - a))
        self.add(self.rng.uniform(a, b, n), tank, self.rng.choice(sensors, n), TURB)

    def clustered_background(self, tank, sensors, a, b, hits_hz, hits=(1, 3), gap_s=(1.2, 3.0)) -> None:
        """Wave hits at ``hits_hz``: each touches one sensor ``hits`` times (uniform), ``gap_s``
        apart (one spacing per hit, jittered 5 %)."""
        rng = self.rng
        for start in rng.uniform(a, b, rng.poisson(hits_hz * (b - a))):
            n, gap = rng.integers(hits[0], hits[1] + 1), rng.uniform(*gap_s)
            t = start + gap * np.arange(n) * rng.uniform(0.95, 1.05, n)
            self.add(t, tank, rng.choice(sensors), TURB)

    def burst(self, tank, sensor, start, hz=None, dur=None) -> None:
        rng = self.rng
        hz = rng.uniform(3, 20) if hz is None else hz
        dur = rng.uniform(0.3, 9.9) if dur is None else dur
        n = max(2, rng.poisson(hz * dur))
        self.add(start + rng.uniform(0, dur, n), tank, sensor, BURST)

    def bursts(self, tank, sensors, a, b, per_hour) -> None:
        for s in self.rng.uniform(a, b, self.rng.poisson(per_hour * (b - a) / 3600)):
            self.burst(tank, self.rng.choice(sensors), s)

    def waves(self, tanks: dict, a, b, per_hour, hit=(3, 6)) -> None:
        """Wave or pump events: each hits several tanks within 3 s, one or two sensors each."""
        rng = self.rng
        names = list(tanks)
        for s in rng.uniform(a, b, rng.poisson(per_hour * (b - a) / 3600)):
            hz, dur = rng.uniform(3, 20), rng.uniform(1, 9.5)
            for tank in rng.choice(names, min(len(names), rng.integers(hit[0], hit[1] + 1)), replace=False):
                for sensor in rng.choice(tanks[tank], min(len(tanks[tank]), rng.integers(1, 3)), replace=False):
                    self.burst(tank, sensor, s + rng.uniform(0, 3), hz * rng.uniform(0.7, 1.0), dur)

    def episode(self, tank, sensors, start, peak_hz, hold_s, ramp_s, paced=False,
                burst_before=False) -> Episode:
        """Fish asking: ramp up, hold, ramp down; contacts split over ``sensors`` unequally."""
        rng = self.rng
        end = start + 2 * ramp_s + hold_s
        if paced:                           # gamma(4) intervals at the peak rate, thinned by the ramp
            gaps = rng.gamma(4.0, 0.25 / peak_hz, int(peak_hz * (end - start) * 1.5) + 10)
            cand = start + np.cumsum(gaps)
            cand = cand[cand < end]
        else:
            cand = start + np.sort(rng.uniform(0, end - start, rng.poisson(peak_hz * (end - start))))
        keep = rng.uniform(size=len(cand)) < np.array([_ramp(x, start, ramp_s, end) for x in cand])
        t = cand[keep]
        w = self.weights.get(tank)
        if w is None:                       # where a sensor sits fixes its share: >= 10 % of two
            w = self.weights[tank] = 0.2 / len(sensors) + 0.8 * rng.dirichlet(np.ones(len(sensors)) * 1.5)
        self.add(t, tank, rng.choice(sensors, len(t), p=w), FISH)
        ep = Episode(tank, start, end, peak_hz, float(t[0]) if len(t) else math.nan)
        self.episodes.append(ep)
        if burst_before and len(t):         # a chatter burst ending 0-5 s before the first contact
            dur = rng.uniform(2, 9.5)
            self.burst(tank, rng.choice(sensors), ep.first - dur - rng.uniform(0, 5), dur=dur)
        return ep

    def stuck(self, tank, sensor, start, end, hz) -> None:
        n = int((end - start) * hz)
        t = start + np.arange(n) / hz + self.rng.uniform(-0.05, 0.05, n) / hz
        self.add(t, tank, sensor, STUCK)
        self.faults.append(Fault(tank, sensor, "stuck", start, end))

    def dead(self, tank, sensor, start, end) -> None:
        self.faults.append(Fault(tank, sensor, "dead", start, end))

    def build(self, tank_days: float) -> Farm:
        t = np.concatenate([p[0] for p in self.parts])
        tank = np.concatenate([np.full(len(p[0]), p[1], dtype=object) for p in self.parts])
        sensor = np.concatenate([p[2] for p in self.parts])
        source = np.concatenate([np.full(len(p[0]), p[3], dtype=np.int8) for p in self.parts])
        keep = np.ones(len(t), bool)
        for f in self.faults:
            if f.kind == "dead":
                keep &= ~((tank == f.tank) & (sensor == f.sensor) & (t >= f.start) & (t < f.end))
        order = np.argsort(t[keep], kind="stable")
        farm = Farm(t[keep][order], tank[keep][order], sensor[keep][order], source[keep][order],
                    self.episodes, self.faults, tank_days, self.background_hz)
        for ep in farm.episodes:            # the first fish contact that reached the filter
            m = (farm.tank == ep.tank) & (farm.source == FISH) & (farm.t >= ep.start) & (farm.t <= ep.end)
            ep.first = float(farm.t[m][0]) if m.any() else math.nan
        farm.episodes = [e for e in farm.episodes if not math.isnan(e.first)]
        return farm


def _ramp(t, start, ramp_s, end) -> float:
    if ramp_s <= 0:
        return 1.0
    return max(0.0, min(1.0, (t - start) / ramp_s, (end - t) / ramp_s))


# -- the named cases ----------------------------------------------------------------------------

SENSORS = ("a", "b")


def _starts(rng, a, b, n, gap=900.0):
    """n episode starts in [a, b), at least ``gap`` apart (fish ask, then rest)."""
    slots = np.arange(a + 3600, b - gap, gap)
    return np.sort(rng.choice(slots, min(n, len(slots)), replace=False) + rng.uniform(0, gap / 3, min(n, len(slots))))


def case(name: str, seed: int = 1, days: float = 2.0) -> Farm:
    """One named hard case: ``days`` tank-days (two sensors a tank, background 0.002–0.02 /s,
    bursts 3 /h, an hour of it first so the filter has measured the tank)."""
    if name == "every":
        return every(seed, days)
    b = Builder(seed)
    rng = b.rng
    ntanks = 12 if name == "wave" else 4
    per_tank = days / ntanks * DAY
    tanks = {f"T{i}": SENSORS if name != "split_sensors" else ("a", "b", "c") for i in range(1, ntanks + 1)}
    for tank, sensors in tanks.items():
        hz = rng.uniform(0.002, 0.02) if name != "busy_0.02" else 0.02
        b.background(tank, sensors, 0, per_tank, hz)
        b.bursts(tank, sensors, 0, per_tank, 3.0)
        for s in _starts(rng, 0, per_tank, int(per_tank / 3600 * 1.5)):
            peak = {"slow_0.10": 0.10, "slow_0.15": 0.15, "slow_0.20": 0.20, "slow_0.30": 0.30,
                    "fast_2.0": 2.0, "paced_0.10": 0.10}.get(name)
            if peak is None:
                peak = float(np.exp(rng.uniform(math.log(0.1), math.log(2.0))))
            ramp = rng.uniform(20, 90) if name == "ramped" else rng.uniform(0, 10)
            b.episode(tank, sensors, s, peak, rng.uniform(60, 600), ramp, paced=name == "paced_0.10",
                      burst_before=name == "burst_before")
        if name == "stuck":
            s = rng.uniform(3600, per_tank - 5400)
            b.stuck(tank, rng.choice(sensors), s, s + rng.uniform(600, 3600), rng.uniform(3, 10))
        if name == "dead":
            s = rng.uniform(3600, per_tank - 9000)
            b.dead(tank, rng.choice(sensors), s, s + rng.uniform(3600, 7200))
    if name == "wave":
        b.waves(tanks, 0, per_tank, 3.0)
    return b.build(days)


def every(seed: int, days: float, peak_hz=(0.4, 2.0)) -> Farm:
    """All the hard parts at once, fish at ``peak_hz``: 8 tanks of 2 or 3 sensors, ramps of
    0–30 s, a burst just before a third of the episodes, waves 2 /h across tanks."""
    b = Builder(seed)
    rng = b.rng
    per_tank = days / 8 * DAY
    tanks = {f"T{i}": SENSORS if i % 2 else ("a", "b", "c") for i in range(1, 9)}
    for tank, sensors in tanks.items():
        b.background(tank, sensors, 0, per_tank, rng.uniform(0.002, 0.02))
        b.bursts(tank, sensors, 0, per_tank, 3.0)
        for s in _starts(rng, 0, per_tank, int(per_tank / 3600 * 1.5)):
            peak = float(np.exp(rng.uniform(math.log(peak_hz[0]), math.log(peak_hz[1]))))
            b.episode(tank, sensors, s, peak, rng.uniform(60, 600), rng.uniform(0, 30),
                      paced=rng.uniform() < 0.3, burst_before=rng.uniform() < 0.3)
    b.waves(tanks, 0, per_tank, 2.0)
    return b.build(days)


CASES = ("band", "slow_0.10", "slow_0.15", "slow_0.20", "slow_0.30", "fast_2.0", "paced_0.10", "ramped",
         "burst_before", "wave", "split_sensors", "busy_0.02", "stuck", "dead")


def null_days(seed: int, days: float, tanks: int = 12) -> Farm:
    """Tanks with no fish: background 0.002–0.02 /s, bursts 3 /h, waves 2 /h across tanks."""
    b = Builder(seed)
    per_tank = days / tanks * DAY
    names = {f"T{i}": SENSORS for i in range(1, tanks + 1)}
    for tank, sensors in names.items():
        b.background(tank, sensors, 0, per_tank, b.rng.uniform(0.002, 0.02))
        b.bursts(tank, sensors, 0, per_tank, 3.0)
    b.waves(names, 0, per_tank, 2.0)
    return b.build(days)


# -- scoring ------------------------------------------------------------------------------------

@dataclass
class Score:
    episodes: int
    caught_60s: int
    latencies: list[float]          # first demand - first contact, per episode (inf: none)
    false_demands: int
    afterglow: int                  # demands <= AFTERGLOW_S after an episode's end (reported apart)
    tank_days: float
    faults: int
    faults_found: int
    wrong_faults: int
    missed: list[Episode]

    @property
    def recall(self) -> float:
        return self.caught_60s / max(1, self.episodes)

    @property
    def false_per_tank_day(self) -> float:
        return self.false_demands / self.tank_days

    def as_dict(self) -> dict:
        lat = sorted(x for x in self.latencies if math.isfinite(x))
        return {"episodes": self.episodes, "recall_60s": round(self.recall, 4),
                "raised": round(len(lat) / max(1, self.episodes), 4),     # at all, before the episode's end
                "latency_p50_s": round(lat[len(lat) // 2], 1) if lat else None,
                "latency_p95_s": round(lat[int(0.95 * (len(lat) - 1))], 1) if lat else None,
                "false_demands": self.false_demands, "afterglow": self.afterglow,
                "false_per_tank_day": round(self.false_per_tank_day, 3),
                "faults": self.faults, "faults_found": self.faults_found, "wrong_faults": self.wrong_faults}


def score(farm: Farm, demands: list[tuple[str, float]], faults: list[tuple[str, str, str, float]]) -> Score:
    """``demands``: (tank, t); ``faults``: (tank, sensor, kind, t) as the filter reported them.
    A demand is false outside every episode's [start, end + AFTERGLOW_S] of its tank; those in
    the afterglow (the fish asked seconds ago: their contacts still fill the window, and the
    next turbulence contact completes it) are counted apart."""
    by_tank: dict[str, list[float]] = {}
    for tank, t in demands:
        by_tank.setdefault(tank, []).append(t)
    lat, caught, missed = [], 0, []
    for ep in farm.episodes:
        ts = [t for t in by_tank.get(ep.tank, ()) if ep.first <= t <= ep.end]
        d = min(ts) - ep.first if ts else math.inf
        lat.append(d)
        if d <= 60.0:
            caught += 1
        else:
            missed.append(ep)
    eps: dict[str, list[Episode]] = {}
    for ep in farm.episodes:
        eps.setdefault(ep.tank, []).append(ep)
    outside = [(tank, t) for tank, t in demands if not any(e.start <= t <= e.end for e in eps.get(tank, ()))]
    glow = sum(any(e.end < t <= e.end + AFTERGLOW_S for e in eps.get(tank, ())) for tank, t in outside)
    false = len(outside) - glow
    found = sum(any(k == f.tank and s == f.sensor and kind == f.kind and f.start <= t <= f.end + 300
                    for k, s, kind, t in faults) for f in farm.faults)
    wrong = sum(not any(k == f.tank and s == f.sensor and kind == f.kind and f.start <= t <= f.end + 300
                        for f in farm.faults) for k, s, kind, t in faults)
    return Score(len(farm.episodes), caught, lat, false, glow, farm.tank_days, len(farm.faults), found, wrong,
                 missed)


def poisson_threshold(b_hz: float, per_day: float = 0.5, window_s: float = 60.0) -> int:
    """The least count k of contacts in a sliding window whose upcrossings under Poisson(b)
    alone (rate b·P[Poisson(bW) = k-1] a second) stay within ``per_day``."""
    k, mean = 1, b_hz * window_s
    while DAY * b_hz * math.exp((k - 1) * math.log(mean) - mean - math.lgamma(k)) > per_day:
        k += 1
    return k


def oracle_recall(farm: Farm, per_day: float = 0.5) -> float:
    """What a detector that knew each tank's true background and saw every fish and turbulence
    contact (bursts and stuck sensors removed perfectly) could catch within 60 s of the first
    contact at ``per_day`` false demands: the count in [first, first + 60 s] against k(b)."""
    ok = 0
    for ep in farm.episodes:
        m = ((farm.tank == ep.tank) & (farm.t >= ep.first) & (farm.t <= ep.first + 60.0)
             & ((farm.source == FISH) | (farm.source == TURB)))
        ok += int(m.sum()) >= poisson_threshold(farm.background_hz[ep.tank], per_day)
    return ok / max(1, len(farm.episodes))
