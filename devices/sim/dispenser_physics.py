"""The simulated dispenser's machine: hopper on a load cell, auger, refill gate.

``DispenserPhysics`` is the machine. State is computed analytically from the farm clock at
every look, so it is right at any clock speed and under a ManualClock:
- the auger delivers ``rate_g_s * drift * (1 + noise)`` g/s, continuously, for the run time the
  device was given; ``noise`` is drawn per run, ``drift`` is a slow random walk from run to run
  (pellet batches change), so the controller has to learn the rate from the load cell;
- an empty hopper delivers nothing; a jam (random per run, or ``inject_jam``) stalls the auger:
  the device ends the run there and latches ``jammed`` until CLEAR_FAULT;
- the refill gate fills the hopper at ``refill_rate_g_s`` up to capacity, only for the time
  the carriage spends at the food box: ``at_food_box(t_from, t_to)`` says how many farm seconds
  of the interval between two looks that was (the PLC in devices/sim/dispenser.py also looks
  every 0.1 s wall while the gate is open);
- an e-stop (``estop``) stops the auger where it is, closes the refill gate and latches: while
  latched the PLC refuses START and GATE_OPEN (``Refused("estop")``) until ``estop_reset``; a
  repeated e-stop changes nothing. The instant the latch is set is kept in ``estops`` (farm time,
  and wall time for benchmarks) and written to the truth log as ``estop``;
- the load cell is the hopper content rounded to the resolution, no other noise; a run's
  grams are the load cell before minus after it;
- every gram that leaves goes to ``deliver(grams, t_from, t_to)``: it left evenly over farm time
  [t_from, t_to] (the auger's rate is constant within a run; t_to is when the hopper ran dry if
  it did), so the simulated world can split it among the tanks the carriage passed over. Both
  callbacks are called with the dispenser's lock held: do not block in them. Grams also go to
  ``physical_total_g``, the exact float the HIL tests take as ground truth.
- ``power_cycle()`` is a site power cut and return: a run in progress stops where it is (its food
  is out, but the PLC never counts it: its RunRecord has ``power_cut`` and no load-cell grams),
  the counters, tags and fault latch are reset as at power-on, the gate closes; the hopper keeps
  its pellets;
- the older callback forms are still accepted, told apart by how many arguments they take:
  ``deliver(grams, t)`` gets everything at the end of the interval, and ``at_food_box(t) -> bool``
  counts an interval as at the box when both its ends are (only right if looks are frequent).
"""
from __future__ import annotations

import inspect
import math
import random
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from devices.dispenser import DispenserState
from devices.dispenser import modbus_dispenser as reg

U32, U64 = 2**32 - 1, 2**64 - 1
Deliver = Callable[[float, float, float], None]       # (grams, t_from, t_to)
TimeAtBox = Callable[[float, float], float]           # (t_from, t_to) -> farm seconds at the food box


class SimDispenserParams(BaseModel):
    """farm.toml ``[sim.dispenser]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    rate_g_s: float = Field(11.0, gt=0, description="true mean auger rate; the controller learns it")
    rate_noise: float = Field(0.04, ge=0, le=0.3, description="sd of the per-run rate factor")
    rate_drift: float = Field(0.01, ge=0, le=0.2, description="sd of the per-run log step of the rate")
    drift_bounds: tuple[float, float] = (0.8, 1.25)
    hopper_capacity_g: float = Field(8000.0, gt=0)
    hopper_start_g: float = Field(6000.0, ge=0)
    refill_rate_g_s: float = Field(400.0, gt=0)
    resolution_g: float = Field(0.1, gt=0, le=65.535)
    jam_probability: float = Field(0.0, ge=0, le=1, description="chance that a run jams")
    seed: int | None = None

    @model_validator(mode="after")
    def _consistent(self):
        if self.hopper_start_g > self.hopper_capacity_g:
            raise ValueError("hopper_start_g exceeds hopper_capacity_g")
        if abs(self.resolution_g * 1000 - round(self.resolution_g * 1000)) > 1e-9:
            raise ValueError("resolution_g must be a whole number of milligrams")
        lo, hi = self.drift_bounds
        if not 0 < lo <= 1 <= hi:
            raise ValueError("drift_bounds must satisfy 0 < low <= 1 <= high")
        return self


class Refused(Exception):
    """The PLC refuses a command; ``reason`` picks the Modbus exception code."""

    def __init__(self, reason: Literal["value", "jammed", "busy", "estop"], text: str):
        super().__init__(text)
        self.reason = reason


@dataclass
class _Run:
    tag: int
    t0: float
    t_end: float               # the device's own timer
    rate_g_s: float
    stall_t: float | None      # a jam stalls the auger here
    before_counts: int         # load cell at the start
    physical_g: float = 0.0

    @property
    def end(self) -> float:
        return self.t_end if self.stall_t is None else min(self.t_end, self.stall_t)


@dataclass(frozen=True)
class RunRecord:
    tag: int
    t_start: float
    t_end: float
    physical_g: float          # what really left the hopper
    measured_g: float          # what the load cell says (LAST_GRAMS); 0 for a run cut by power
    jammed: bool
    power_cut: bool = False    # the run ended by a power cut: the PLC never counted it


def _positional(fn: Callable) -> int:
    """How many positional arguments ``fn`` takes (many, for ``*args``)."""
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):          # no signature to read: assume the current form
        return 99
    if any(p.kind is p.VAR_POSITIONAL for p in params):
        return 99
    return sum(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params)


def interval_deliver(deliver: Callable | None) -> Deliver:
    """``deliver`` in its current form; ``deliver(grams, t)`` gets it all at the end."""
    if deliver is None:
        return lambda grams, t_from, t_to: None
    if _positional(deliver) >= 3:
        return deliver
    return lambda grams, t_from, t_to: deliver(grams, t_to)


def interval_at_box(at_food_box: Callable | None) -> TimeAtBox:
    """``at_food_box`` in its current form; ``at_food_box(t) -> bool`` is judged at both ends."""
    if at_food_box is None:
        return lambda t_from, t_to: t_to - t_from
    if _positional(at_food_box) >= 2:
        return at_food_box
    return lambda t_from, t_to: t_to - t_from if at_food_box(t_from) and at_food_box(t_to) else 0.0


class DispenserPhysics:
    def __init__(self, params: SimDispenserParams, clock, deliver: Deliver | None = None,
                 at_food_box: TimeAtBox | None = None, truth=None):
        self.params = params
        self.clock = clock
        self._deliver = interval_deliver(deliver)
        self._time_at_box = interval_at_box(at_food_box)
        self._truth = truth
        self._rng = random.Random(params.seed)
        self._lock = threading.RLock()
        self._res_mg = round(params.resolution_g * 1000)
        self._t = clock.now()
        self._hopper = params.hopper_start_g
        self._run: _Run | None = None
        self._gate = self._jammed = self._estop = False
        self.estops: list[tuple[float, float]] = []     # (farm t, wall time.time()) each latch was set
        self._jam_next: float | None = None
        self.drift = 1.0
        self.cycles = self.last_tag = self.last_counts = self.total_counts = 0
        self.physical_total_g = 0.0
        self.runs: list[RunRecord] = []
        self.power_cycles = 0

    # -- commands (the PLC's) ---------------------------------------------------------
    def start_run(self, run_s: float, tag: int) -> None:
        with self._lock:
            self._advance(self.clock.now())
            if self._estop:             # before anything else: a latched e-stop refuses every start
                raise Refused("estop", "e-stop latched: reset it first")
            # the tag first: a resent start is a duplicate whatever its run left behind (a jam)
            if not 0 < tag < 65536 or tag in (self.last_tag, self._run.tag if self._run else 0):
                raise Refused("value", f"tag {tag} out of range or same as the running or last run's")
            if self._jammed:
                raise Refused("jammed", "auger jammed: clear the fault first")
            if self._run is not None or self._gate:
                raise Refused("busy", "auger running or refill gate open")
            if not 0 < run_s <= reg.MAX_RUN_MS / 1000:
                raise Refused("value", f"run time {run_s} s out of range")
            t0 = self._t
            self._run = _Run(tag, t0, t0 + run_s, self._next_rate(), self._stall_at(t0, run_s),
                             self._counts(self._hopper))
            if self._truth is not None:
                self._truth.write("auger_start", t0, tag=tag, run_s=run_s)

    def stop_auger(self) -> None:
        with self._lock:
            self._advance(self.clock.now())
            if self._run is not None:
                self._finish(self._t, jammed=False)

    def set_gate(self, open_gate: bool) -> None:
        with self._lock:
            self._advance(self.clock.now())
            if open_gate and self._estop:
                raise Refused("estop", "e-stop latched: reset it first")
            if open_gate and self._run is not None:
                raise Refused("busy", "auger running")
            self._gate = open_gate

    def clear_fault(self) -> None:
        with self._lock:
            self._advance(self.clock.now())
            self._jammed = False

    def estop(self) -> None:
        """Auger off where it is, gate closed, latch set: the PLC's own e-stop relay."""
        with self._lock:
            wall = time.time()
            self._advance(self.clock.now())
            if self._run is not None:
                self._finish(self._t, jammed=False)
            self._gate = False
            if not self._estop:
                self._estop = True
                self.estops.append((self._t, wall))
                if self._truth is not None:
                    self._truth.write("estop", self._t, device="dispenser", wall=wall)

    def estop_reset(self) -> None:
        with self._lock:
            self._advance(self.clock.now())
            self._estop = False

    @property
    def estop_latched(self) -> bool:
        return self._estop

    # -- for the simulated world and tests ----------------------------------------------
    def power_cycle(self) -> None:
        """Power off and on: as after a site power cut, the PLC forgets everything it counted."""
        with self._lock:
            self._advance(self.clock.now())
            run, self._run = self._run, None
            if run is not None:
                record = RunRecord(run.tag, run.t0, self._t, run.physical_g, 0.0, False, power_cut=True)
                self.runs.append(record)
                if self._truth is not None:
                    self._truth.write("auger_run", self._t, t_start=round(run.t0, 4), tag=run.tag,
                                      physical_g=run.physical_g, measured_g=None, jammed=False, power_cut=True)
            self.cycles = self.last_tag = self.last_counts = self.total_counts = 0
            self._gate = self._jammed = False
            self._jam_next = None
            self.power_cycles += 1
            if self._truth is not None:
                self._truth.write("dispenser_power_cycle", self._t, count=self.power_cycles)

    def inject_jam(self, at_fraction: float = 0.5) -> None:
        """Jam the run in progress now, or the next run at ``at_fraction`` of its time."""
        with self._lock:
            self._advance(self.clock.now())
            if self._run is not None:
                self._run.stall_t = self._t
                self._advance(self._t)
            else:
                self._jam_next = at_fraction

    def update(self) -> None:
        with self._lock:
            self._advance(self.clock.now())

    def read(self) -> DispenserState:
        """What the driver would read now (the same decoding)."""
        return reg.state_from_fields(self.status_fields())

    def status_fields(self) -> tuple[int, ...]:
        """The status block now, in STATUS_FORMAT order."""
        with self._lock:
            self._advance(self.clock.now())
            bits = ((reg.RUNNING if self._run else 0) | (reg.JAMMED if self._jammed else 0)
                    | (reg.REFILLING if self._gate else 0) | (reg.ESTOP_LATCHED if self._estop else 0))
            return (bits, self._run.tag if self._run else 0, self._counts(self._hopper), self.cycles,
                    self.last_tag, self.last_counts, self.total_counts, self._res_mg)

    @property
    def hopper_g(self) -> float:
        with self._lock:
            self._advance(self.clock.now())
            return self._hopper

    @property
    def refilling(self) -> bool:
        return self._gate

    def next_event_t(self) -> float | None:
        """Farm time of the next thing that happens without a command (run end, hopper full:
        the latter if the carriage, as it moves now, stays at the food box until then)."""
        with self._lock:
            if self._run is not None:
                return self._run.end
            if self._gate and self._hopper < self.params.hopper_capacity_g:
                need = (self.params.hopper_capacity_g - self._hopper) / self.params.refill_rate_g_s
                if self._time_at_box(self._t, self._t + need) >= need * (1 - 1e-9):
                    return self._t + need
            return None

    # -- the machine ------------------------------------------------------------------
    def _advance(self, now: float) -> None:
        run = self._run
        if run is not None:
            self._flow(run, min(now, run.end))
            if run.end <= now:
                self._finish(run.end, jammed=run.stall_t is not None and run.stall_t <= run.t_end)
        elif self._gate and now > self._t and self._hopper < self.params.hopper_capacity_g:
            # filling only raises the level, so the order of the spells at the box does not matter
            at_box = self._time_at_box(self._t, now)
            if at_box > 0:
                self._hopper = min(self.params.hopper_capacity_g,
                                   self._hopper + self.params.refill_rate_g_s * at_box)
        self._t = max(self._t, now)

    def _flow(self, run: _Run, upto: float) -> None:
        t_from = self._t
        if upto <= t_from:
            return
        full = run.rate_g_s * (upto - t_from)
        grams = min(self._hopper, full)
        self._t = upto
        if grams > 0:
            self._hopper -= grams
            run.physical_g += grams
            self.physical_total_g += grams
            # an emptied hopper stops the flow early: the food fell over the first part only
            self._deliver(grams, t_from, upto if grams == full else t_from + grams / run.rate_g_s)

    def _finish(self, t: float, jammed: bool) -> None:
        run, self._run = self._run, None
        grams = max(0, run.before_counts - self._counts(self._hopper))
        self.cycles = (self.cycles + 1) & U32
        self.last_tag, self.last_counts = run.tag, grams
        self.total_counts = (self.total_counts + grams) & U64
        self._jammed = self._jammed or jammed
        record = RunRecord(run.tag, run.t0, t, run.physical_g, grams * self._res_mg / 1000, jammed)
        self.runs.append(record)
        if self._truth is not None:
            self._truth.write("auger_run", t, t_start=round(run.t0, 4), tag=run.tag, physical_g=run.physical_g,
                              measured_g=record.measured_g, jammed=jammed)
            if jammed:
                self._truth.write("jam", t, tag=run.tag)

    def _next_rate(self) -> float:
        p = self.params
        lo, hi = p.drift_bounds
        self.drift = min(hi, max(lo, self.drift * math.exp(self._rng.gauss(0.0, p.rate_drift))))
        # pellets in a turning auger vary, but within bounds: an auger that sometimes threw out
        # double its dose would be broken, not noisy. Three standard deviations either way.
        spread = 3.0 * p.rate_noise
        noise = min(1.0 + spread, max(1.0 - spread, 1.0 + self._rng.gauss(0.0, p.rate_noise)))
        return p.rate_g_s * self.drift * noise

    def _stall_at(self, t0: float, run_s: float) -> float | None:
        fraction, self._jam_next = self._jam_next, None
        if fraction is None and self._rng.random() < self.params.jam_probability:
            fraction = self._rng.uniform(0.05, 0.95)
        return None if fraction is None else t0 + fraction * run_s

    def _counts(self, grams: float) -> int:
        return round(grams * 1000 / self._res_mg)
