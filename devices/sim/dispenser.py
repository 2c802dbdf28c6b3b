"""The simulated dispenser's PLC on Modbus TCP; the machine it drives is in
devices/sim/dispenser_physics.py (re-exported here).

``SimDispenser`` is the PLC: a pymodbus TCP server whose device is declared as data (SimData
blocks laid out as in devices/dispenser/modbus_dispenser.py) plus a behaviour callback
(``SimDevice.action``), pymodbus's own way to simulate a device: a read refreshes the status
block from the physics at that instant; a write to COMMAND runs the command. The end of a run
is scheduled with an asyncio timer in wall time, so counters advance without a read.
"""
from __future__ import annotations

import asyncio
import math
import threading

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from devices.dispenser import modbus_dispenser as reg
from devices.sim.dispenser_physics import DispenserPhysics, Refused, RunRecord, SimDispenserParams

__all__ = ["DispenserPhysics", "Refused", "RunRecord", "SimDispenser", "SimDispenserParams"]

REFILL_TICK_S = 0.1   # wall seconds between looks while the gate is open (keeps intervals short)
REFUSAL_CODE = {"value": reg.ILLEGAL_VALUE, "jammed": reg.DEVICE_FAILURE, "busy": reg.DEVICE_BUSY,
                "estop": reg.DEVICE_FAILURE}


class SimDispenser:
    """The PLC on Modbus TCP. ``start()``/``stop()`` in a running loop, or ``start_thread()``.
    ``deliver`` and ``at_food_box``: see devices/sim/dispenser_physics.py."""

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
    def power_cycle(self) -> None:
        """A site power cut and return: connections drop, the PLC's counters reset (see
        ``DispenserPhysics.power_cycle``); it serves again at once on the same port."""
        def cycle():
            self.physics.power_cycle()
            self._drop()
            self._schedule()
        if self._loop is None or not self._loop.is_running():
            self.physics.power_cycle()
        else:
            self._in_loop(cycle)

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
                   reg.GATE_CLOSE: lambda: physics.set_gate(False), reg.ESTOP: physics.estop,
                   reg.ESTOP_RESET: physics.estop_reset}
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
