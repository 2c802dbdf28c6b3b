"""The thrusters' motor controller on a serial line (pyserial), line protocol in protocol.py.

A reader thread owns the port's input: it parses every line, notes each status (for ``status()``
and the e-stop lane, under a threading lock, never via the loop) and hands replies to the loop
with ``call_soon_threadsafe``. Writes go under one lock held for the write alone, so the e-stop
lane's ``trip_estop`` (any thread) writes its frame at once, never behind a command waiting for
its reply. A command takes a seq 1..65535 and waits ``command_timeout_s`` (wall) for its reply;
the device sends a status before every reply, so when ``drive()`` returns ``status()`` already
shows its effect. ``trip_estop`` uses seq 0 (nobody waits for its reply) and waits for a status
with the latch flag instead.

Lines that do not parse (noise, a wrong checksum, a command letter from the device) are counted
in ``malformed`` and skipped. The port vanishing (EIO on a pty whose other end closed, a USB
adapter unplugged) is LinkDown from then on; the controller opens a fresh driver.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import select
import threading
import time
from typing import Any

import serial
from pydantic import Field

from devices.base import Section
from devices.errors import DeviceFault, DeviceTimeout, LinkDown, ProtocolError
from devices.thrusters import EstopLatched, Thrusters, ThrusterState
from devices.thrusters import protocol as p

log = logging.getLogger(__name__)
READ_TIMEOUT_S = 0.05       # the reader thread's longest nap: how soon close() is noticed


class Config(Section):
    port: str = Field(min_length=1, description="serial device (/dev/ttyUSB0, a pty) or a pyserial URL")
    baudrate: int = Field(115200, gt=0)
    status_timeout_s: float = Field(0.5, gt=0, le=60, description="wall seconds without a status = silence")
    command_timeout_s: float = Field(0.5, gt=0, le=60, description="wall seconds to wait for a reply")
    estop_timeout_s: float = Field(0.1, gt=0, le=5, description="wall seconds trip_estop waits for the latch")
    watchdog_s: float | None = Field(None, ge=0.05, le=600,
                                     description="farm seconds; set in the device on open (default: its own)")


def _refusal(name: str, what: str, result: int) -> Exception:
    if result == p.Result.ESTOP:
        return EstopLatched(name, f"{what} refused: e-stop latched")
    try:
        why = p.Result(result).name
    except ValueError:
        why = f"result {result}"
    if result == p.Result.FAULT:
        return DeviceFault(name, f"{what} refused: thruster controller in fault")
    return ProtocolError(name, f"{what} refused: {why}")


class SerialThrusters(Thrusters):
    Config = Config

    def __init__(self, name: str, config: Config, clock: Any):
        super().__init__(name, config, clock)
        self.malformed = 0                  # lines rejected
        self.lines = 0                      # valid lines
        self._ser: serial.Serial | None = None
        self._reader: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping = threading.Event()
        self._write_lock = threading.Lock()
        self._cond = threading.Condition()            # a status arrived; guards the fields below
        self._latest: ThrusterState | None = None
        self._latest_at = time.monotonic()
        self._seen_estop_at = -math.inf
        self._link_error: str | None = None
        self._pending: dict[int, tuple[str, asyncio.Future]] = {}
        self._seq = 0
        self._tripped = False                         # our own trip, until a reset is accepted

    # --- link -----------------------------------------------------------------------------------
    async def _open(self) -> None:
        cfg = self.config
        try:
            self._ser = serial.serial_for_url(cfg.port, baudrate=cfg.baudrate, timeout=READ_TIMEOUT_S,
                                              write_timeout=cfg.estop_timeout_s,   # for fd-less URLs
                                              exclusive=True)     # never a port another process reads
            self._ser.reset_input_buffer()
            with contextlib.suppress(AttributeError, NotImplementedError):
                os.set_blocking(self._ser.fileno(), False)      # _put waits with its own bound
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkDown(self.name, f"cannot open {cfg.port}: {exc}") from None
        self._loop = asyncio.get_running_loop()
        self._latest_at = time.monotonic()
        self._reader = threading.Thread(target=self._read_lines, args=(self._ser,),
                                        name=f"{self.name}-reader", daemon=True)
        self._reader.start()
        if cfg.watchdog_s is not None:
            await self._set_watchdog(cfg.watchdog_s)

    async def _close(self) -> None:
        self._stopping.set()
        ser, self._ser = self._ser, None
        if ser is not None:
            with contextlib.suppress(Exception):
                ser.cancel_read()
        if self._reader is not None:
            await asyncio.to_thread(self._reader.join, 2.0)
            self._reader = None
        if ser is not None:
            with self._write_lock:
                ser.close()
        self._fail_pending("closed")

    def _lost(self, why: str) -> None:
        with self._cond:
            self._link_error = self._link_error or why
            self._cond.notify_all()
        self._fail_pending(why)

    def _fail_pending(self, why: str) -> None:
        pending, self._pending = self._pending, {}
        loop = self._loop
        for what, fut in pending.values():
            exc = LinkDown(self.name, f"{what}: {why}")
            if loop is not None:
                with contextlib.suppress(RuntimeError):
                    loop.call_soon_threadsafe(_settle, fut, exc)

    def _write(self, data: bytes) -> None:
        """One line out, within ``estop_timeout_s``: DeviceTimeout when the line takes nothing that
        long (the far end not reading), LinkDown when the port is gone."""
        ser = self._ser
        if ser is None or self._link_error is not None:
            raise LinkDown(self.name, f"{self.config.port}: {self._link_error or 'not open'}")
        try:
            with self._write_lock:
                self._put(ser, data)
        except _WriteTimeout:
            raise DeviceTimeout(self.name, f"{self.config.port}: the line took nothing for "
                                           f"{self.config.estop_timeout_s:g} s") from None
        except (serial.SerialException, OSError, AttributeError, TypeError, ValueError) as exc:
            self._lost(f"write failed: {exc}")
            raise LinkDown(self.name, f"{self.config.port}: write failed: {exc}") from None

    def _put(self, ser: serial.Serial, data: bytes) -> None:
        # Not ser.write(): with a write timeout, pyserial raises "Write timeout" after a write that
        # went through whenever the thread was held up past the timeout (a loaded machine), and a
        # line that was sent would be reported lost. The port's fd is non-blocking (pyserial's).
        try:
            fd = ser.fileno()
        except (AttributeError, OSError, ValueError, NotImplementedError):
            ser.write(data)                       # a URL backend without a descriptor
            return
        deadline = time.monotonic() + self.config.estop_timeout_s
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(fd, view):]
                continue
            except BlockingIOError:
                pass
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([], [fd], [], left)[1]:
                raise _WriteTimeout

    # --- the reader thread ----------------------------------------------------------------------
    def _read_lines(self, ser: serial.Serial) -> None:
        lines = p.Lines()
        while not self._stopping.is_set():
            try:
                data = ser.read(max(1, ser.in_waiting))
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if not self._stopping.is_set():
                    self._lost(f"{self.config.port}: port gone ({exc})")
                return
            if not data:
                continue
            torn = lines.torn
            for raw in lines.feed(data):
                self._on_line(raw)
            self.malformed += lines.torn - torn

    def _on_line(self, raw: bytes) -> None:
        line = p.parse(raw)
        st = p.parse_status(line) if line is not None and line.kind == "T" else None
        if st is not None:
            self.lines += 1
            return self._note(st)
        if line is not None and line.kind == "A":
            self.lines += 1
            seq, result = line.fields
            what, fut = self._pending.pop(seq, (None, None))
            if fut is not None and self._loop is not None:
                with contextlib.suppress(RuntimeError):
                    self._loop.call_soon_threadsafe(_settle, fut, result, what)
            return
        if raw.strip():
            self.malformed += 1

    def _note(self, st: p.Status) -> None:
        state = ThrusterState(st.t, st.left, st.right, st.estop, st.watchdog, p.fault_name(st.fault))
        now = time.monotonic()
        with self._cond:
            self._latest, self._latest_at = state, now
            if st.estop:
                self._seen_estop_at = now
            self._cond.notify_all()

    # --- commands -------------------------------------------------------------------------------
    async def _command(self, what: str, encode, *args) -> None:
        if self._link_error is not None:
            raise LinkDown(self.name, f"{what} not sent: {self._link_error}")
        self._seq = self._seq % 65535 + 1                 # 1..65535; 0 is the e-stop lane's
        seq = self._seq
        fut = asyncio.get_running_loop().create_future()
        self._pending[seq] = (what, fut)
        try:
            self._write(encode(seq, *args))
        except (LinkDown, DeviceTimeout):
            self._pending.pop(seq, None)
            raise
        try:
            result = await asyncio.wait_for(fut, self.config.command_timeout_s)
        except TimeoutError:
            self._pending.pop(seq, None)
            raise DeviceTimeout(self.name, f"no reply to {what} (seq {seq}) in "
                                           f"{self.config.command_timeout_s:g} s") from None
        if result != p.Result.ACCEPTED:
            raise _refusal(self.name, what, result)

    async def _drive(self, left: float, right: float) -> None:
        latest = self._latest
        if self._tripped or (latest is not None and latest.estop):
            raise EstopLatched(self.name, "drive refused: e-stop latched")
        await self._command("drive", p.drive_line, left, right)

    async def _stop(self) -> None:
        await self._command("stop", p.stop_line)

    async def _reset_estop(self) -> None:
        await self._command("reset", p.reset_line)
        self._tripped = False

    async def _set_watchdog(self, watchdog_s: float) -> None:
        await self._command("watchdog", p.watchdog_line, watchdog_s)

    def _trip_estop(self) -> ThrusterState:
        self._tripped = True                      # refuse drives from here on, whatever the line does
        sent = time.monotonic()
        self._write(p.estop_line(0))
        deadline = sent + self.config.estop_timeout_s
        with self._cond:
            while self._seen_estop_at < sent and self._link_error is None:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            latest, fresh = self._latest, self._latest_at >= sent
            seen, down = self._seen_estop_at >= sent, self._link_error
        if seen:
            return latest
        if down is not None:
            raise LinkDown(self.name, f"e-stop: {down}")
        if latest is None or not fresh:
            raise DeviceTimeout(self.name, f"e-stop sent, no status in {self.config.estop_timeout_s:g} s")
        return latest                             # a status after the send, latch not shown yet

    def _estop_seen_since(self, t: float) -> bool:
        return self._seen_estop_at >= t

    def _status(self) -> ThrusterState | None:
        if self._link_error is not None and self._opened:
            raise LinkDown(self.name, self._link_error)
        quiet = time.monotonic() - self._latest_at
        if self._opened and quiet > self.config.status_timeout_s:
            raise DeviceTimeout(self.name, f"no status for {quiet:.2f} s")
        return self._latest


class _WriteTimeout(Exception):
    pass


def _settle(fut: asyncio.Future, result, what: str | None = None) -> None:
    if fut.done():
        return
    if isinstance(result, BaseException):
        fut.set_exception(result)
    else:
        fut.set_result(result)
