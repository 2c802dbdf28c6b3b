"""The simulated dispenser: hopper on a load cell, auger, refill gate, and its PLC on Modbus TCP.

``DispenserPhysics`` is the machine. State is computed analytically from the farm clock at
every look, so it is right at any clock speed and under a ManualClock:
- the auger delivers ``rate_g_s * drift * (1 + noise)`` g/s, continuously, for the run time the
  device was given; ``noise`` is drawn per run, ``drift`` is a slow random walk from run to run
  (pellet batches change), so the controller has to learn the rate from the load cell;
- an empty hopper delivers nothing; a jam (random per run, or ``inject_jam``) stalls the auger:
  the device ends the run there and latches ``jammed`` until CLEAR_FAULT;
- the refill gate fills the hopper at ``refill_rate_g_s`` up to capacity, only while
  ``at_food_box(t)`` holds (checked at both ends of each interval between looks; a server
  timer looks every 0.1 s wall while the gate is open);
- the load cell is the hopper content rounded to the resolution, no other noise; a run's
  grams are the load cell before minus after it;
- every gram that leaves goes to ``deliver(grams, t)`` (the simulated world routes it to the
  tank under the robot; called with the dispenser's lock held, so do not block in it) and to
  ``physical_total_g``, the exact float the HIL tests take as ground truth.

``SimDispenser`` is the PLC: a pymodbus TCP server whose device is declared as data (SimData
blocks laid out as in devices/dispenser/modbus_dispenser.py) plus a behaviour callback
(``SimDevice.action``), pymodbus's own way to simulate a device: a read refreshes the status
block from the physics at that instant; a write to COMMAND runs the command. The end of a run
is scheduled with an asyncio timer in wall time, so counters advance without a read.
"""
from __future__ import annotations

import asyncio
import math
import random
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from devices.dispenser import DispenserState
from devices.dispenser import modbus_dispenser as reg

U32, U64 = 2**32 - 1, 2**64 - 1
REFILL_TICK_S = 0.1   # wall seconds between looks while the gate is open
REFUSAL_CODE = {"value": reg.ILLEGAL_VALUE, "jammed": reg.DEVICE_FAILURE, "busy": reg.DEVICE_BUSY}


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

    def __init__(self, reason: Literal["value", "jammed", "busy"], text: str):
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
    measured_g: float          # what the load cell says (LAST_GRAMS)
    jammed: bool


class DispenserPhysics:
    def __init__(self, params: SimDispenserParams, clock,
                 deliver: Callable[[float, float], None] | None = None,
                 at_food_box: Callable[[float], bool] | None = None, truth=None):
        self.params = params
        self.clock = clock
        self._deliver = deliver or (lambda grams, t: None)
        self._at_food_box = at_food_box or (lambda t: True)
        self._truth = truth
        self._rng = random.Random(params.seed)
        self._lock = threading.RLock()
        self._res_mg = round(params.resolution_g * 1000)
        self._t = clock.now()
        self._hopper = params.hopper_start_g
        self._run: _Run | None = None
        self._gate = self._jammed = False
        self._jam_next: float | None = None
        self.drift = 1.0
        self.cycles = self.last_tag = self.last_counts = self.total_counts = 0
        self.physical_total_g = 0.0
        self.runs: list[RunRecord] = []

    # -- commands (the PLC's) ---------------------------------------------------------
    def start_run(self, run_s: float, tag: int) -> None:
        with self._lock:
            self._advance(self.clock.now())
            if self._jammed:
                raise Refused("jammed", "auger jammed: clear the fault first")
            if self._run is not None or self._gate:
                raise Refused("busy", "auger running or refill gate open")
            if not 0 < run_s <= reg.MAX_RUN_MS / 1000:
                raise Refused("value", f"run time {run_s} s out of range")
            if not 0 < tag < 65536 or tag == self.last_tag:
                raise Refused("value", f"tag {tag} out of range or same as the last run's")
            t0 = self._t
            self._run = _Run(tag, t0, t0 + run_s, self._next_rate(), self._stall_at(t0, run_s),
                             self._counts(self._hopper))

    def stop_auger(self) -> None:
        with self._lock:
            self._advance(self.clock.now())
            if self._run is not None:
                self._finish(self._t, jammed=False)

    def set_gate(self, open_gate: bool) -> None:
        with self._lock:
            self._advance(self.clock.now())
            if open_gate and self._run is not None:
                raise Refused("busy", "auger running")
            self._gate = open_gate

    def clear_fault(self) -> None:
        with self._lock:
            self._advance(self.clock.now())
            self._jammed = False

    # -- for the simulated world and tests ----------------------------------------------
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
                    | (reg.REFILLING if self._gate else 0))
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
        """Farm time of the next thing that happens without a command (run end, hopper full)."""
        with self._lock:
            if self._run is not None:
                return self._run.end
            if self._gate and self._at_food_box(self._t) and self._hopper < self.params.hopper_capacity_g:
                return self._t + (self.params.hopper_capacity_g - self._hopper) / self.params.refill_rate_g_s
            return None

    # -- the machine ------------------------------------------------------------------
    def _advance(self, now: float) -> None:
        run = self._run
        if run is not None:
            self._flow(run, min(now, run.end))
            if run.end <= now:
                self._finish(run.end, jammed=run.stall_t is not None and run.stall_t <= run.t_end)
        elif self._gate and now > self._t and self._at_food_box(self._t) and self._at_food_box(now):
            self._hopper = min(self.params.hopper_capacity_g,
                               self._hopper + self.params.refill_rate_g_s * (now - self._t))
        self._t = max(self._t, now)

    def _flow(self, run: _Run, upto: float) -> None:
        grams = min(self._hopper, run.rate_g_s * (upto - self._t)) if upto > self._t else 0.0
        self._t = max(self._t, upto)
        if grams > 0:
            self._hopper -= grams
            run.physical_g += grams
            self.physical_total_g += grams
            self._deliver(grams, upto)

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


class SimDispenser:
    """The PLC on Modbus TCP. ``start()``/``stop()`` in a running loop, or ``start_thread()``."""

    def __init__(self, params: SimDispenserParams, clock, *, host: str = "127.0.0.1", port: int = 0,
                 unit: int = 1, deliver=None, at_food_box=None, truth=None):
        self.physics = DispenserPhysics(params, clock, deliver, at_food_box, truth)
        self.clock = clock
        self.host, self.port, self.unit = host, port, unit
        self._server: ModbusTcpServer | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._unresponsive = False
        self._forced: list[int] = []

    @property
    def physical_total_g(self) -> float:
        """Every gram the auger has let out up to now, exact (the HIL ground truth)."""
        self.physics.update()
        return self.physics.physical_total_g

    def inject_jam(self, at_fraction: float = 0.5) -> None:
        self.physics.inject_jam(at_fraction)
        self._in_loop(self._tick)

    # -- fault injection -------------------------------------------------------------
    def set_unresponsive(self, on: bool) -> None:
        """Keep connections open but answer nothing (the client times out)."""
        self._unresponsive = on

    def inject_exception(self, code: int, count: int = 1) -> None:
        """Answer the next ``count`` requests with Modbus exception ``code``."""
        self._forced.extend([code] * count)

    def drop_connections(self) -> None:
        self._in_loop(self._drop)

    def _drop(self) -> None:
        if self._server is not None:
            for connection in list(self._server.active_connections.values()):
                connection.close()

    # -- serving -------------------------------------------------------------------------
    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        device = SimDevice(self.unit, action=self._action, simdata=[
            SimData(reg.STATUS_ADDR, count=reg.STATUS_REGS, datatype=DataType.REGISTERS, readonly=True),
            SimData(reg.COMMAND_ADDR, count=reg.COMMAND_REGS, datatype=DataType.REGISTERS)])
        self._server = ModbusTcpServer(device, address=(self.host, self.port), trace_pdu=self._trace_pdu)
        try:
            await self._server.serve_forever(background=True)
        except RuntimeError:
            self._server = None
            raise OSError(f"simulated dispenser cannot listen on {self.host}:{self.port}") from None
        self.port = self._server.transport.sockets[0].getsockname()[1]
        self._schedule()

    async def stop(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._server is not None:
            server, self._server = self._server, None
            await server.shutdown()

    def start_thread(self) -> SimDispenser:
        """Serve from a thread of its own (its own event loop); returns once listening."""
        ready, failed = threading.Event(), []

        def serve():
            loop = asyncio.new_event_loop()
            try:
                loop.run_until_complete(self.start())
            except OSError as exc:
                failed.append(exc)
                ready.set()
                return loop.close()
            ready.set()
            loop.run_forever()
            loop.run_until_complete(self.stop())
            loop.close()

        self._thread = threading.Thread(target=serve, name="sim-dispenser", daemon=True)
        self._thread.start()
        ready.wait(10)
        if failed:
            self._thread = None
            raise failed[0]
        return self

    def stop_thread(self) -> None:
        if self._thread is not None:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(10)
            self._thread = None

    def _in_loop(self, fn) -> None:
        """Run ``fn`` on the server's loop (it owns the timers and connections)."""
        if self._loop is None or not self._loop.is_running():
            return None
        if self._thread is None or threading.current_thread() is self._thread:
            return fn()
        done = threading.Event()
        self._loop.call_soon_threadsafe(lambda: (fn(), done.set()))
        done.wait(5)

    def _trace_pdu(self, sending: bool, pdu):
        # A request traced to None is never handled: the connection stays open, no answer.
        return None if self._unresponsive and not sending else pdu

    async def _action(self, fc, start, address, count, registers, values):
        if self._forced:
            return ExcCodes(self._forced.pop(0))
        if values is None:
            at = reg.STATUS_ADDR - start
            registers[at:at + reg.STATUS_REGS] = reg.to_registers(reg.STATUS_FORMAT,
                                                                  *self.physics.status_fields())
            return None
        return self._command(start, address, registers, values)

    def _command(self, start: int, address: int, registers: list[int], values: list[int]):
        at = reg.COMMAND_ADDR - start
        block = registers[at:at + reg.COMMAND_REGS]
        block[address - reg.COMMAND_ADDR:address - reg.COMMAND_ADDR + len(values)] = values
        if address + len(values) <= reg.COMMAND_REG:
            return None        # parameters only; they wait for a COMMAND write
        run_ms, tag, command = reg.from_registers(reg.COMMAND_FORMAT, block)
        physics = self.physics
        actions = {reg.START: lambda: physics.start_run(run_ms / 1000, tag), reg.STOP: physics.stop_auger,
                   reg.CLEAR_FAULT: physics.clear_fault, reg.GATE_OPEN: lambda: physics.set_gate(True),
                   reg.GATE_CLOSE: lambda: physics.set_gate(False)}
        try:
            if command not in actions:
                raise Refused("value", f"unknown command {command}")
            actions[command]()
        except Refused as exc:
            return ExcCodes(REFUSAL_CODE[exc.reason])
        self._schedule()
        return None

    def _schedule(self) -> None:
        """Look at the physics again when something will happen by itself (run end, refill)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._server is None or not math.isfinite(self.clock.speed):
            return      # a ManualClock has no wall time to wait for: reads bring physics up to date
        t = self.physics.next_event_t()
        delay = math.inf if t is None else self.clock.wall(max(0.0, t - self.clock.now()))
        if self.physics.refilling:
            delay = min(delay, REFILL_TICK_S)
        if math.isfinite(delay):
            self._timer = self._loop.call_later(delay, self._tick)

    def _tick(self) -> None:
        self._timer = None
        self.physics.update()
        self._schedule()
