"""The dispenser PLC over Modbus TCP, through pymodbus 3.16's ``AsyncModbusTcpClient``.

Register map (holding registers; FC3 and FC4 read the same cells). Words are big-endian and
32/64-bit values put the high word first. Grams travel as load-cell counts of RES_MG mg.

  status block, read-only, 14 registers read in ONE request (one consistent snapshot):
  100      STATE       bit0 running, bit1 jammed (latched until CLEAR_FAULT), bit2 refill gate open,
                       bit3 e-stop latched (until ESTOP_RESET)
  101      RUN_TAG     tag of the run in progress, 0 when the auger is idle
  102-103  HOPPER      uint32 counts: the load cell now
  104-105  CYCLES      uint32: finished runs (completed, stopped or jammed) since power-on
  106      LAST_TAG    tag of the last finished run
  107-108  LAST_GRAMS  uint32 counts: load cell before that run minus after it
  109-112  TOTAL       uint64 counts: sum of LAST_GRAMS since power-on
  113      RES_MG      milligrams per count (100 = 0.1 g)
  command block, read/write:
  200-201  RUN_MS      uint32 farm milliseconds, 1..600000, timed by the device itself
  202      TAG         1..65535, must differ from RUN_TAG and LAST_TAG
  203      COMMAND     1 START (RUN_MS, TAG), 2 STOP, 3 CLEAR_FAULT, 4 GATE_OPEN, 5 GATE_CLOSE,
                       6 ESTOP (auger off, gate closed, latch set), 7 ESTOP_RESET (latch released)
  A start is one FC16 write of 200-203, so its parameters and its trigger arrive together.

Exception responses: 02 address outside the map, or a write to the status block; 03 RUN_MS or
TAG out of range, TAG equal to RUN_TAG or LAST_TAG, unknown command; 04 START or GATE_OPEN while the e-stop is
latched (checked before anything else), START while jammed; 06 START while running or with the
gate open, GATE_OPEN while running. ESTOP and ESTOP_RESET are never refused; ESTOP repeated is
harmless. Only ESTOP_RESET releases the latch (CLEAR_FAULT does not). A START's TAG is checked
first, so a resent start is refused 03 whatever state its run left; the driver does not rely on
that: any refused START whose tag the counters show running or done counts as accepted.

The e-stop has a priority lane: ``trip_estop()`` writes ESTOP and reads STATE back over a second
connection of its own (pymodbus's synchronous client, made for the calling thread, ``retries`` 0,
``estop_timeout_s``), which no queued request of the main connection can delay. It blocks the
calling thread, so call it from a thread of its own, never from the event loop.

Errors: no connection -> LinkDown; no reply after ``retries`` resends -> DeviceTimeout (LinkDown
if the connection went meanwhile); exception response -> DeviceRefused, a DeviceFault carrying
``code``. The client does not reconnect in the background: the next call after a drop does, and
a call that finds its (older) connection dead reconnects and sends once more before LinkDown.
"""
from __future__ import annotations

import asyncio
import struct
import threading

from pydantic import Field
from pymodbus.client import AsyncModbusTcpClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from devices.base import Section
from devices.dispenser import Dispenser, DispenserState
from devices.errors import DeviceFault, DeviceTimeout, LinkDown, ProtocolError
from devices.modbus_link import connect_timeout_field, connect_within

STATUS_ADDR, STATUS_FORMAT = 100, ">HHIIHIQH"   # STATE RUN_TAG HOPPER CYCLES LAST_TAG LAST TOTAL RES
COMMAND_ADDR, COMMAND_FORMAT = 200, ">IHH"      # RUN_MS TAG COMMAND
STATUS_REGS = struct.calcsize(STATUS_FORMAT) // 2
COMMAND_REGS = struct.calcsize(COMMAND_FORMAT) // 2
COMMAND_REG = COMMAND_ADDR + COMMAND_REGS - 1
RUNNING, JAMMED, REFILLING, ESTOP_LATCHED = 1, 2, 4, 8
START, STOP, CLEAR_FAULT, GATE_OPEN, GATE_CLOSE, ESTOP, ESTOP_RESET = 1, 2, 3, 4, 5, 6, 7
MAX_RUN_MS = 600_000
ILLEGAL_ADDRESS, ILLEGAL_VALUE, DEVICE_FAILURE, DEVICE_BUSY = 2, 3, 4, 6
MEANING = {
    ILLEGAL_ADDRESS: "illegal address",
    ILLEGAL_VALUE: "illegal value: run time or tag out of range, or tag already used by the last run",
    DEVICE_FAILURE: "device failure: e-stop latched (until estop_reset), or on a start: auger jammed "
                    "(latched until clear_fault)",
    DEVICE_BUSY: "busy: auger running or refill gate open",
}


def to_registers(fmt: str, *values: int) -> list[int]:
    raw = struct.pack(fmt, *values)
    return list(struct.unpack(f">{len(raw) // 2}H", raw))


def from_registers(fmt: str, registers: list[int]) -> tuple[int, ...]:
    return struct.unpack(fmt, struct.pack(f">{len(registers)}H", *registers))


def state_from_fields(fields: tuple[int, ...]) -> DispenserState:
    """The status block's fields (in STATUS_FORMAT order) as the farm reads them."""
    bits, run_tag, hopper, cycles, last_tag, last, total, res_mg = fields
    return DispenserState(
        hopper_g=hopper * res_mg / 1000, running=bool(bits & RUNNING), jammed=bool(bits & JAMMED),
        refilling=bool(bits & REFILLING), cycles=cycles, last_tag=last_tag,
        last_grams=last * res_mg / 1000, total_grams=total * res_mg / 1000,
        resolution_g=res_mg / 1000, run_tag=run_tag, estop=bool(bits & ESTOP_LATCHED))


class DeviceRefused(DeviceFault):
    """The dispenser answered with a Modbus exception response; ``code`` is its exception code."""

    def __init__(self, device: str, what: str, code: int):
        super().__init__(device, f"{what} refused: Modbus exception {code:#04x} "
                                 f"({MEANING.get(code, 'device-specific')})")
        self.code = code


class Config(Section):
    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(502, ge=1, le=65535)
    unit: int = Field(1, ge=0, le=247)
    timeout_s: float = Field(1.0, gt=0, le=60, description="wall seconds to wait for one reply")
    retries: int = Field(1, ge=0, le=10, description="resends of an unanswered request")
    estop_timeout_s: float = Field(0.1, gt=0, le=10, description="wall seconds for one e-stop exchange")
    connect_timeout_s: float = connect_timeout_field()


class ModbusDispenser(Dispenser):
    Config = Config

    def __init__(self, name: str, config: Config, clock):
        super().__init__(name, config, clock)
        self._client: AsyncModbusTcpClient | None = None
        self._in_flight = False
        self._seen: DispenserState | None = None     # the last status read: counters to compare
        self._lane: ModbusTcpClient | None = None        # the e-stop's own connection
        self._lane_lock = threading.Lock()

    async def _open(self) -> None:
        await self._connected()
        # warm the e-stop connection now, so a trip does not pay for a connect (best effort: a
        # trip connects again if this one failed or was closed by the PLC)
        await asyncio.to_thread(self._lane_client)

    async def _close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        lane, self._lane = self._lane, None
        if lane is not None:
            lane.close()

    # -- the e-stop lane (any thread but the loop's) ------------------------------------------
    def _trip_estop(self) -> DispenserState:
        with self._lane_lock:
            client = self._lane_client()
            if client is None:
                raise LinkDown(self.name, f"e-stop: cannot connect to {self.config.host}:{self.config.port}")
            try:
                for attempt in (0, 1):   # a connection the PLC closed while idle is found dead once
                    try:
                        reply = client.write_register(COMMAND_REG, ESTOP, device_id=self.config.unit)
                        break
                    except (ConnectionException, OSError):
                        client.close()
                        if attempt or not client.connect():
                            raise
                if reply.isError():
                    raise DeviceRefused(self.name, "e-stop", reply.exception_code)
                reply = client.read_holding_registers(STATUS_ADDR, count=STATUS_REGS,
                                                      device_id=self.config.unit)
            except (ConnectionException, OSError) as exc:
                client.close()
                raise LinkDown(self.name, f"e-stop: connection lost ({exc})") from None
            except ModbusIOException:
                client.close()       # a late answer must not be read as the next one's
                raise DeviceTimeout(self.name, f"e-stop: no reply within {self.config.estop_timeout_s} s") from None
            except ModbusException as exc:
                client.close()
                raise ProtocolError(self.name, f"e-stop: {exc}") from None
            if reply.isError():
                raise DeviceRefused(self.name, "e-stop status read", reply.exception_code)
            if len(reply.registers) != STATUS_REGS:
                raise ProtocolError(self.name, f"status read returned {len(reply.registers)} registers")
            return state_from_fields(from_registers(STATUS_FORMAT, reply.registers))

    def _lane_client(self) -> ModbusTcpClient | None:
        """The e-stop connection, connected; None when the dispenser cannot be reached."""
        if self._closed:
            return None
        if self._lane is None:
            cfg = self.config
            self._lane = ModbusTcpClient(cfg.host, port=cfg.port, timeout=cfg.estop_timeout_s, retries=0,
                                         reconnect_delay=0, name=f"{self.name}-estop")
        lane = self._lane
        return lane if lane.connected or lane.connect() else None

    async def _read(self) -> DispenserState:
        reply = await self._request("read", lambda c: c.read_holding_registers(
            STATUS_ADDR, count=STATUS_REGS, device_id=self.config.unit))
        if len(reply.registers) != STATUS_REGS:
            raise ProtocolError(self.name, f"status read returned {len(reply.registers)} registers")
        state = self._weighed(reply.registers)
        self._seen = state
        return state

    def _weighed(self, registers: list[int]) -> DispenserState:
        """The status block as the feeder reads grams from it (the e-stop lane reads only STATE)."""
        state = state_from_fields(from_registers(STATUS_FORMAT, registers))
        if state.resolution_g <= 0:
            # every gram read as 0: a dispense booked as 0 g, a full hopper read empty and refilled
            raise ProtocolError(self.name, "status block: RES_MG is 0 mg per count: the load cell cannot be read")
        return state

    async def _run_auger(self, run_s: float, tag: int) -> None:
        block = to_registers(COMMAND_FORMAT, max(1, round(run_s * 1000)), tag, START)
        try:
            await self._request(f"start of run {tag}", lambda c: c.write_registers(
                COMMAND_ADDR, block, device_id=self.config.unit), before_resend=self._may_resend_start(tag))
        except DeviceRefused:
            # A start resent after a lost reply (by pymodbus or by a restarted controller) is
            # refused, as a duplicate tag, as busy, or as jammed when that very run jammed; the
            # code depends on the PLC's order of checks. If the run it asked for exists, that is
            # success, whatever the code: the counters say so.
            if (await self._read()).fate(tag) != "not_started":
                return
            raise

    async def _stop(self) -> None:
        await self._command("stop", STOP)

    async def _set_refill(self, open_gate: bool) -> None:
        await self._command("refill gate", GATE_OPEN if open_gate else GATE_CLOSE)

    async def _clear_fault(self) -> None:
        await self._command("clear fault", CLEAR_FAULT)

    async def _reset_estop(self) -> None:
        await self._command("e-stop reset", ESTOP_RESET)

    async def _command(self, what: str, command: int) -> None:
        unit = self.config.unit
        await self._request(what, lambda c: c.write_register(COMMAND_REG, command, device_id=unit))

    async def _connected(self) -> AsyncModbusTcpClient:
        cfg = self.config
        if self._closed:
            raise LinkDown(self.name, "dispenser link is closed")
        if self._client is None:
            # reconnect_delay=0: no background reconnect loop; the next call reconnects.
            self._client = AsyncModbusTcpClient(
                cfg.host, port=cfg.port, timeout=cfg.timeout_s, retries=cfg.retries,
                reconnect_delay=0, name=self.name, trace_connect=self._link_changed)
        if not self._client.connected and not await connect_within(self._client, cfg.connect_timeout_s):
            raise LinkDown(self.name, f"cannot connect to {cfg.host}:{cfg.port}")
        return self._client

    def _link_changed(self, connected: bool) -> None:
        # pymodbus notices a dropped connection but lets the pending request run out its
        # timeout (and resends); fail it at once instead, so a drop reads as LinkDown.
        future = getattr(self._client.ctx, "response_future", None) if self._client else None
        if not connected and self._in_flight and future is not None and not future.done():
            future.set_exception(ConnectionException("connection lost"))

    def _may_resend_start(self, tag: int):
        """Before a START goes out again on a new connection: the PLC behind it may have restarted
        (a power cut mid-request drops the connection too) and forgotten the tag, so it would run
        the portion twice. Resend only when its counters are where they were before the first try."""
        before = self._seen

        async def check(client) -> bool:
            reply = await self._exchange("status before resending a start", client, lambda c:
                                         c.read_holding_registers(STATUS_ADDR, count=STATUS_REGS,
                                                                  device_id=self.config.unit))
            now = self._weighed(reply.registers)
            self._seen = now
            if now.fate(tag) != "not_started":
                return False                      # it got there the first time: nothing to resend
            lighter = before is not None and before.hopper_g - now.hopper_g > 1.5 * now.resolution_g
            if before is None or now.cycles < before.cycles or now.total_grams < before.total_grams or lighter:
                raise DeviceFault(self.name, f"start of run {tag}: the dispenser restarted (counters reset "
                                             f"or food gone uncounted) while it was sent; not sent again")
            return True
        return check

    async def _request(self, what: str, send, before_resend=None):
        stale = self._client is not None and self._client.connected
        try:
            return await self._exchange(what, await self._connected(), send)
        except LinkDown:
            if not stale:
                raise
        # The connection predates this call and was found dead (PLCs close idle connections):
        # reconnect and send once more. Every command here is idempotent (starts are, by tag,
        # unless the PLC restarted meanwhile: ``before_resend`` looks first).
        client = await self._connected()
        if before_resend is not None and not await before_resend(client):
            return None
        return await self._exchange(what, client, send)

    async def _exchange(self, what: str, client: AsyncModbusTcpClient, send):
        self._in_flight = True
        try:
            reply = await send(client)
        except ConnectionException as exc:
            raise LinkDown(self.name, f"{what}: connection lost ({exc})") from None
        except ModbusIOException:
            if not client.connected:
                raise LinkDown(self.name, f"{what}: connection lost") from None
            raise DeviceTimeout(self.name, f"{what}: no reply within {self.config.timeout_s} s "
                                           f"({self.config.retries} resends)") from None
        except ModbusException as exc:
            raise ProtocolError(self.name, f"{what}: {exc}") from None
        finally:
            self._in_flight = False
        if reply.isError():
            raise DeviceRefused(self.name, what, reply.exception_code)
        return reply
