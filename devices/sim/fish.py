"""A simulated tank of fish and its contact sensors: hunger, demand, eating, turbulence, faults.

Hunger (grams the fish would eat) grows at ``appetite = biomass × ration_pct_day / 100`` per day
since the last meal. When it reaches ``hunger_threshold_g`` (about one portion) the fish start
asking: an *episode* of contacts at a rate drawn in ``rate_hz`` (log-uniform), spread over the
tank's sensors: ``paced`` (the default) is a school bumping at a steady pace, the first contact
as the episode starts and each interval the mean ± ``pace_jitter``; ``poisson`` is memoryless.
Food delivered with ``feed(grams, t)`` lowers hunger; the episode ends when the fish have eaten
enough (hunger below ``sated_fraction`` × threshold) or when they give up (after a duration
drawn in ``duration_s``, then a ``rest_s`` pause before asking again).

Around the fish: sparse turbulence and chatter bursts, stuck and dead sensors, from
devices/sim/contact_streams.py, generated in fixed 10-minute chunks of farm time from their own
random stream, so a run is the same for a seed whatever the caller's step.

Defaults make the demo farm ask for about its daily ration (2.5 % of biomass) in ~60 g
portions: T1 (2,400 fish × 18 g) needs 1,080 g a day, i.e. an episode every ~80 min once fed.
Fish span the contract's whole band, 0.1–2 /s, over calm tanks (0.005 /s). Poisson fish at
0.1 /s cannot all be served within 60 s at any useful false-demand rate, and 0.02 /s of
turbulence hides them more often than not (controller/demand.py, *Slow fish*): set
``pattern = "poisson"`` or raise ``turbulence_hz`` to study that.
"""
from __future__ import annotations

import bisect
import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from devices.sim import contact_streams as cs

CHUNK_S = 600.0


class SimFishParams(BaseModel):
    """farm.toml ``[sim.fish]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    ration_pct_day: float = Field(2.5, gt=0, le=20, description="appetite, % of biomass a day")
    hunger_threshold_g: float = Field(60.0, gt=0, description="hunger that starts an episode")
    meals_per_day: float | None = Field(None, gt=0, le=48, description="the threshold is this share of a day's "
                                        "appetite instead (it grows with the fish): a farm's few large meals")
    initial_hunger: float = Field(0.5, ge=0, le=2, description="hunger at start, × threshold")
    sated_fraction: float = Field(0.25, ge=0, lt=1)
    rate_hz: tuple[float, float] = (0.1, 2.0)
    pattern: Literal["paced", "poisson"] = "paced"
    pace_jitter: float = Field(0.2, ge=0, lt=1, description="paced: each interval the mean ± this share")
    duration_s: tuple[float, float] = (60.0, 600.0)
    rest_s: float = Field(900.0, ge=0, description="pause after giving up before asking again")
    turbulence_hz: float = Field(0.005, ge=0)
    bursts_per_hour: float = Field(2.0, ge=0)
    stuck_per_day: float = Field(0.0, ge=0)
    dead_per_day: float = Field(0.0, ge=0)
    fault_s: tuple[float, float] = (600.0, 3600.0)
    stuck_rate_hz: float = Field(5.0, gt=0)
    feeding_hours: tuple[float, float] | None = Field(None, description="local hours [from, to) the fish ask "
                                                      "for food in (fish feed by day); None: round the clock")

    @model_validator(mode="after")
    def _spans(self):
        # a negative rate drew from log(-1): fish that never asked for food, and no word said
        for name in ("rate_hz", "duration_s", "fault_s"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"{name} must be [low, high] with 0 < low <= high, not [{lo:g}, {hi:g}]")
        if self.feeding_hours is not None and not all(0 <= h <= 24 for h in self.feeding_hours):
            raise ValueError(f"feeding_hours must lie in 0..24, not {list(self.feeding_hours)}")
        return self


class SimTank:
    """The physical tank. ``contacts_until(t)`` advances it; ``feed(grams, t)`` feeds it."""

    def __init__(self, tank_cfg, params: SimFishParams, rng: np.random.Generator, truth=None,
                 t0: float | None = None, utc_offset_h: float = 0.0):
        """``t0``: farm time the simulation starts; by default the first call's time.
        ``utc_offset_h``: the farm's, for ``feeding_hours``."""
        self.utc_offset_s = utc_offset_h * 3600.0
        self.id = tank_cfg.id
        self.sensors = list(tank_cfg.sensors)
        self.p = params
        self.truth = truth
        self.rng = rng                                      # fish behaviour
        self._bg_rng = np.random.default_rng(rng.integers(2**63))  # turbulence and faults
        self._count0 = tank_cfg.stock
        self.stock = None                                   # devices/sim/stock.SimStock: the fish grow
        self.species = tank_cfg.species
        self.weight0_g = tank_cfg.mean_weight_g
        self.hunger_g = params.initial_hunger * self.threshold_g
        self.rate_hz = 0.0                                  # > 0 while the fish ask
        self._give_up = self._next_fish = math.inf
        self.heeded_t = -math.inf                          # the episode's start or its last meal
        self._bg: list[tuple[float, str]] = []
        self._dead: list[tuple[str, float, float]] = []
        self._out: list[tuple[float, str]] = []
        if t0 is not None:
            self._begin(t0)

    def _begin(self, t0: float) -> None:
        self.t = self._rest_until = t0
        self._chunk_end = math.floor(t0 / CHUNK_S) * CHUNK_S

    # -- public -------------------------------------------------------------------------------
    @property
    def appetite_g_s(self) -> float:
        """Grams a second the fish would eat: their biomass now (growing, with a stock) x the ration."""
        biomass = self.stock.biomass_g if self.stock is not None else self._count0 * self.weight0_g
        return max(biomass, 1e-9) * self.p.ration_pct_day / 100 / 86400

    @property
    def threshold_g(self) -> float:
        """Hunger that starts an episode: ``hunger_threshold_g``, or with ``meals_per_day`` that share
        of a day's appetite (a grow-out's fish, fed a few large meals that grow with them)."""
        if self.p.meals_per_day is None:
            return self.p.hunger_threshold_g
        return self.appetite_g_s * 86400.0 / self.p.meals_per_day

    @property
    def asking(self) -> bool:
        return self.rate_hz > 0

    def next_episode(self, now: float) -> float:
        """Farm time the fish will next start asking, as things stand (``now`` while they ask or
        before the tank has begun): hunger grows at a known pace, so the simulator knows it ahead."""
        if self.asking or not hasattr(self, "t"):
            return now
        need = max(0.0, self.threshold_g - self.hunger_g)
        return self._by_day(max(self._rest_until, self.t + need / self.appetite_g_s))

    def unheeded_until(self) -> float:
        """While the fish ask: the earliest an episode can start again if nobody feeds them (they
        give up, then rest); inf otherwise."""
        return self._give_up + self.p.rest_s if self.asking else math.inf

    def contacts_until(self, t: float) -> list[tuple[float, str]]:
        """Advance to farm time ``t``; the contacts since the last call, sorted by time."""
        self._advance(t)
        out, self._out = self._out, []
        out.sort()
        return out

    def feed(self, grams: float, t: float) -> None:
        """Food reaches the water at ``t``: the fish eat it, and stop asking once sated."""
        self._advance(t)
        if self.stock is not None:
            self.stock.feed(grams, t)
        self.hunger_g = max(0.0, self.hunger_g - grams)
        self.heeded_t = t
        if self.truth is not None:
            self.truth.write("fed", t, tank=self.id, grams=round(grams, 3))
        if self.asking and self.hunger_g <= self.p.sated_fraction * self.threshold_g:
            self._end_episode(t, "fed")

    # -- fish ---------------------------------------------------------------------------------
    def _advance(self, t: float) -> None:
        if not hasattr(self, "t"):
            self._begin(t)
        while self._chunk_end <= t:                 # dead spells known before fish contacts
            self._draw_chunk(self._chunk_end, self._chunk_end + CHUNK_S)
            self._chunk_end += CHUNK_S
        while self.t < t:
            if self.asking:
                end = min(t, self._give_up)
                self._fish_contacts(end)
                self.hunger_g += self.appetite_g_s * (end - self.t)
                self.t = end
                if end >= self._give_up:
                    self._end_episode(end, "gave up")
                    self._rest_until = end + self.p.rest_s
            else:
                need = self.threshold_g - self.hunger_g
                start = self._by_day(max(self._rest_until, self.t + max(0.0, need) / self.appetite_g_s))
                end = min(t, start)
                self.hunger_g += self.appetite_g_s * (end - self.t)
                self.t = end
                if end >= start:
                    self._start_episode(start)
        self._background(t)
        if self.stock is not None:
            self.stock.advance(t)

    def _by_day(self, t: float) -> float:
        """``t``, or the next start of the feeding hours when ``t`` falls outside them."""
        if self.p.feeding_hours is None:
            return t
        start_h, end_h = self.p.feeding_hours
        local = t + self.utc_offset_s
        day = math.floor(local / 86400.0) * 86400.0
        hour = (local - day) / 3600.0
        inside = start_h <= hour < end_h if start_h <= end_h else (hour >= start_h or hour < end_h)
        if inside:
            return t
        opens = day + start_h * 3600.0
        return (opens if opens > local else opens + 86400.0) - self.utc_offset_s

    def _start_episode(self, t: float) -> None:
        lo, hi = np.log(self.p.rate_hz[0]), np.log(self.p.rate_hz[1])
        self.rate_hz = float(np.exp(self.rng.uniform(lo, hi)))
        self._give_up = t + float(self.rng.uniform(*self.p.duration_s))
        self._next_fish = t if self.p.pattern == "paced" else t + self._interval()
        self.heeded_t = t
        if self.truth is not None:
            self.truth.write("episode_start", t, tank=self.id, rate_hz=round(self.rate_hz, 4))

    def _end_episode(self, t: float, why: str) -> None:
        if self.truth is not None:
            self.truth.write("episode_end", t, tank=self.id, rate_hz=round(self.rate_hz, 4), why=why)
        self.rate_hz = 0.0
        self._give_up = self._next_fish = math.inf

    def _fish_contacts(self, until: float) -> None:
        n = len(self.sensors)
        while self._next_fish < until:
            t = self._next_fish
            self._emit(t, self.sensors[int(self.rng.integers(n))] if n > 1 else self.sensors[0])
            self._next_fish = t + self._interval()

    def _interval(self) -> float:
        if self.p.pattern == "paced":
            return float(self.rng.uniform(1.0 - self.p.pace_jitter, 1.0 + self.p.pace_jitter)) / self.rate_hz
        return float(self.rng.exponential(1.0 / self.rate_hz))

    def _emit(self, t: float, sensor: str) -> None:
        for who, a, b in self._dead:
            if who == sensor and a <= t < b:
                return
        self._out.append((t, sensor))

    # -- surroundings -------------------------------------------------------------------------
    def _background(self, t: float) -> None:
        """Turbulence, bursts and faults up to ``t`` (drawn a whole chunk at a time)."""
        due = bisect.bisect_left(self._bg, (t,))
        for c in self._bg[:due]:
            self._emit(*c)
        del self._bg[:due]
        self._dead = [d for d in self._dead if d[2] > t]

    def _draw_chunk(self, a: float, b: float) -> None:
        rng, p = self._bg_rng, self.p
        parts = [cs.turbulence(rng, self.id, self.sensors, a, b, p.turbulence_hz),
                 cs.chatter_bursts(rng, self.id, self.sensors, a, b, p.bursts_per_hour)]
        for start in cs.poisson_times(rng, p.stuck_per_day / 86400.0, a, b).tolist():
            sensor = self.sensors[int(rng.integers(len(self.sensors)))]
            parts.append(cs.stuck_sensor(rng, self.id, sensor, start, start + rng.uniform(*p.fault_s),
                                         p.stuck_rate_hz))
        for start in cs.poisson_times(rng, p.dead_per_day / 86400.0, a, b).tolist():
            sensor = self.sensors[int(rng.integers(len(self.sensors)))]
            end = start + float(rng.uniform(*p.fault_s))
            self._dead.append((sensor, start, end))
            self._log("sensor_fault", start, sensor=sensor, fault="dead", until=round(end, 3))
        chunk = cs.merge(*parts)
        for burst in chunk.bursts:
            self._log("burst", burst.start, sensor=burst.sensor, duration_s=round(burst.duration_s, 3))
        for fault in chunk.faults:
            self._log("sensor_fault", fault.start, sensor=fault.sensor, fault=fault.kind,
                      until=round(fault.end, 3))
        self._bg.extend(zip(chunk.t.tolist(), chunk.sensor.tolist(), strict=True))
        self._bg.sort()

    def _log(self, kind: str, t: float, **fields) -> None:
        if self.truth is not None:
            self.truth.write(kind, t, tank=self.id, **fields)
