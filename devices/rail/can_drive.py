"""The rail drive on CAN: the driver that speaks the motor controller's frames (devices/rail/can_frames.py).

python-can does the bus work (``can.Bus`` for any interface, ``can.Notifier`` feeding the asyncio
loop); this module only knows the drive's behaviour.

The drive sends a status frame at once on every state change and as a heartbeat (wall period);
an accepted command is answered by a status frame carrying its seq, then the reply, so when a
command returns the driver's status already shows its effect.

E-stop lane: ``trip_estop()`` sends ESTOP with seq 0 (nobody waits for its reply) straight onto
the bus from the calling thread, under the lock every send takes, so no queued request delays
it; ``estop_seen_since(t)`` says whether a status frame in "estop" has arrived since ``t``
(``time.monotonic``). Frames are read on python-can's reader thread, which notes each status
frame there before handing it to the loop, so the lane's confirmation never waits for the loop.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from typing import Any

import can
from pydantic import Field, field_validator, model_validator

from devices import serial_lock
from devices.base import Section
from devices.errors import DeviceFault, DeviceTimeout, LinkDown
from devices.rail import RailDrive, RailStatus
from devices.rail.can_frames import (
    REPLY_BASE,
    STATES,
    STATUS_BASE,
    Command,
    Op,
    Reason,
    StatusFrame,
    _why,
)

log = logging.getLogger(__name__)

LAST_LISTEN_S = 0.1   # wall: how long a last listen for frames lasts before silence is declared


class LinkNotifier(can.Notifier):
    """can.Notifier whose reader ends quietly on a dead link, after telling the listeners.

    python-can re-raises a read error from its reader thread (a traceback on stderr) and, when
    it watches the bus's file descriptor from the loop, keeps calling a reader that fails on a
    hung-up serial line on every loop turn. A dead line is an event the drive reports, not a crash.
    """

    def _rx_thread(self, bus: can.BusABC) -> None:
        try:
            super()._rx_thread(bus)
        except Exception:  # noqa: BLE001 - already handed to the listeners' on_error
            pass

    def _on_message_available(self, bus: can.BusABC) -> None:
        try:
            super()._on_message_available(bus)
        except Exception as exc:  # noqa: BLE001
            for fd in self._readers:
                if isinstance(fd, int):
                    self._loop.remove_reader(fd)
            self.exception = exc
            self._on_error(exc)


class _ReaderEnds(Exception):
    """Raised from the reader thread's error handler: a dead link ends the reader."""


class _Inbox(can.Listener):
    """Runs on the reader thread: notes status frames for the e-stop lane, hands everything to
    the loop (in arrival order) for the rest."""

    def __init__(self, drive: CanRailDrive, bus: can.BusABC, loop: asyncio.AbstractEventLoop):
        self.drive, self.bus, self.loop = drive, bus, loop

    def on_message_received(self, msg: can.Message) -> None:
        self.drive._note_frame(msg)
        with contextlib.suppress(RuntimeError):  # the loop closed: the driver is gone
            self.loop.call_soon_threadsafe(self.drive._on_frame, msg)

    def on_error(self, exc: Exception) -> None:
        with contextlib.suppress(RuntimeError):
            self.loop.call_soon_threadsafe(self._lost, exc)
        raise _ReaderEnds from exc               # a reader on a dead line would spin on its errors

    def _lost(self, exc: Exception) -> None:
        if self.bus is self.drive._bus:          # a late word from a bus already replaced is moot
            self.drive._on_link_error(exc)


# The bitrates an slcan adapter knows (its S0..S8 codes, and S9 for 83.3k).
SLCAN_BITRATES = (10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 750_000, 1_000_000, 83_300)


class Config(Section):
    interface: str = Field("slcan", description='"virtual", "slcan" or any python-can interface')
    channel: str = Field(min_length=1, description="serial port for slcan, channel name for virtual/socketcan")
    bitrate: int = Field(500_000, ge=1_000, le=8_000_000)
    node_id: int = Field(1, ge=1, le=127)
    status_timeout_s: float = Field(0.5, gt=0, le=60, description="wall seconds without a status frame = silence")
    command_timeout_s: float = Field(0.5, gt=0, le=60, description="wall seconds to wait for a reply")
    move_speed_m_s: float = Field(0.0, ge=0, le=65.0, description="0: the drive's maximum")
    sleep_after_open_s: float = Field(0.0, ge=0, le=60, description="slcan: 2 for adapters that reset on open")
    options: dict[str, Any] = Field({}, description="further keyword arguments for can.Bus")

    @field_validator("interface")
    @classmethod
    def _known_interface(cls, interface: str) -> str:
        # a typo was an alarm retried for good ("Unknown interface type"), not bad input
        if interface not in can.VALID_INTERFACES:
            raise ValueError(f"interface must be one of python-can's: {', '.join(sorted(can.VALID_INTERFACES))}")
        return interface

    @model_validator(mode="after")
    def _slcan_bitrate(self):
        if self.interface == "slcan" and self.bitrate not in SLCAN_BITRATES:
            raise ValueError(f"bitrate must be one of {', '.join(map(str, SLCAN_BITRATES))} for slcan")
        return self


class CanRailDrive(RailDrive):
    Config = Config

    def __init__(self, name: str, config: Config, clock: Any):
        super().__init__(name, config, clock)
        self._bus: can.BusABC | None = None
        self._notifier: LinkNotifier | None = None
        self._port_lock: int | None = None     # devices.serial_lock: the slcan port held for this process
        self._link_error: str | None = None
        self._latest: RailStatus | None = None
        self._last_rx = time.monotonic()       # wall: silence is a property of the link
        self._changed = asyncio.Event()        # replaced after every status frame
        self._pending: dict[int, tuple[Op, asyncio.Future]] = {}
        self._seq = 0
        self._relink = asyncio.Lock()
        self._send_lock = threading.Lock()     # the loop and the e-stop lane both send
        self._seen_estop_at = -math.inf        # monotonic: last status frame in "estop" (reader thread)

    # --- link -----------------------------------------------------------------------------------
    async def _open(self) -> None:
        await self._connect()

    async def _close(self) -> None:
        self._drop_link("closed")

    async def _connect(self) -> None:
        cfg = self.config
        node = cfg.node_id
        kwargs = dict(cfg.options)
        if cfg.interface == "slcan":
            kwargs.setdefault("sleep_after_open", cfg.sleep_after_open_s)
            # python-can's slcan reads byte by byte, each read waiting up to the serial timeout
            # (1 ms by default): the reader thread would wake (and take the GIL) 1000 times a
            # second on an idle line. A read returns as soon as a byte comes, whatever this is.
            kwargs.setdefault("timeout", 0.02)
        filters = [{"can_id": base + node, "can_mask": 0x7FF, "extended": False}
                   for base in (STATUS_BASE, REPLY_BASE)]
        try:   # the port's lock first: nothing is written to a port another process holds
            lock = serial_lock.hold(str(cfg.channel).split("@")[0]) if cfg.interface == "slcan" else None
        except OSError as exc:
            raise LinkDown(self.name, f"cannot open CAN {cfg.interface} {cfg.channel}: {exc}") from None
        try:   # opening an slcan adapter blocks (serial open, setup commands): keep it off the loop
            bus = await asyncio.to_thread(can.Bus, interface=cfg.interface, channel=cfg.channel,
                                          bitrate=cfg.bitrate, can_filters=filters, **kwargs)
        except (can.CanError, OSError, ValueError, TypeError, ImportError) as exc:
            serial_lock.release(lock)
            raise LinkDown(self.name, f"cannot open CAN {cfg.interface} {cfg.channel}: {exc}") from None
        self._port_lock = lock
        self._bus, self._link_error = bus, None
        self._last_rx = time.monotonic()
        self._latest = None
        # no loop for the notifier: its reader thread reads every bus (never the loop's add_reader),
        # so status frames are seen by the e-stop lane even while the loop is busy
        self._notifier = LinkNotifier(bus, [_Inbox(self, bus, asyncio.get_running_loop())], timeout=0.02)

    def _drop_link(self, why: str) -> None:
        """Forget the bus: fail whoever waits for a reply, stop the reader, release the port."""
        self._link_error = self._link_error or why
        for _op, fut in self._pending.values():
            if not fut.done():
                fut.set_exception(LinkDown(self.name, f"CAN link down: {self._link_error}"))
        self._pending.clear()
        notifier, bus, self._notifier, self._bus = self._notifier, self._bus, None, None
        if notifier is not None:
            notifier.stop(timeout=0.5)
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError) as exc:
                # python-can's slcan writes "C" before closing its port: on a dead line that
                # write fails and the port would stay open (one fd lost per link drop).
                log.debug("%s: shutdown of a dead bus: %s", self.name, exc)
                port = getattr(bus, "serialPortOrig", None)
                if port is not None:
                    port.close()
        serial_lock.release(self._port_lock)
        self._port_lock = None
        self._wake()

    def _on_link_error(self, exc: Exception) -> None:
        # python-can's "Could not read from serial device" hides the serial port's own reason
        # (EIO: unplugged; readiness without data: another reader) in its cause
        cause = f" ({exc.__cause__})" if exc.__cause__ is not None else ""
        log.warning("%s: CAN link lost: %s%s", self.name, exc, cause)
        self._link_error = f"{type(exc).__name__}: {exc}{cause}"
        self._drop_link(self._link_error)

    # --- the e-stop lane (any thread) --------------------------------------------------------
    def trip_estop(self) -> None:
        """Send ESTOP now, from the calling thread; LinkDown when the bus is gone. Confirm with
        ``estop_seen_since``: the drive reports "estop" in its next status frame."""
        bus = self._bus
        if bus is None:
            raise LinkDown(self.name, f"e-stop not sent: CAN link down ({self._link_error or 'not open'})")
        msg = Command(Op.ESTOP, 0).to_message(self.config.node_id)
        try:
            with self._send_lock:
                bus.send(msg, timeout=self.config.command_timeout_s)
        except (can.CanError, OSError, AttributeError) as exc:   # AttributeError: closed under us
            raise LinkDown(self.name, f"e-stop not sent: {exc}") from None

    def estop_seen_since(self, t: float) -> bool:
        """A status frame in "estop" arrived at or after ``t`` (``time.monotonic()``)."""
        return self._seen_estop_at >= t

    def _note_frame(self, msg: can.Message) -> None:
        if msg.arbitration_id == STATUS_BASE + self.config.node_id and len(msg.data) == 8:
            if msg.data[5] & 0x07 == STATES.index("estop"):
                self._seen_estop_at = time.monotonic()

    # --- frames in ------------------------------------------------------------------------------
    def _on_frame(self, msg: can.Message) -> None:
        node = self.config.node_id
        if msg.arbitration_id == STATUS_BASE + node:
            try:
                frame = StatusFrame.from_bytes(msg.data)
            except ValueError as exc:
                log.warning("%s: ignored status frame: %s", self.name, exc)
                return
            self._last_rx = time.monotonic()
            self._latest = RailStatus(self.clock.now(), frame.position_m, frame.velocity_m_s, frame.state,
                                      frame.homed, frame.fault_code, frame.at_target, frame.at_limit)
            self._wake()
        elif msg.arbitration_id == REPLY_BASE + node and len(msg.data) >= 3:
            seq, reason = msg.data[0], msg.data[2]
            op, fut = self._pending.pop(seq, (None, None))
            if fut is None or fut.done():
                return
            if reason == Reason.ACCEPTED:
                fut.set_result(None)
            else:
                fut.set_exception(DeviceFault(self.name, f"{op.name} rejected: {_why(reason)}"))

    def _wake(self) -> None:
        self._changed.set()
        self._changed = asyncio.Event()

    # --- the RailDrive interface ----------------------------------------------------------------
    async def _command(self, what: str, arg: float | None = None) -> None:
        op = {"home": Op.HOME, "move": Op.MOVE, "stop": Op.STOP, "estop": Op.ESTOP,
              "clear": Op.CLEAR_FAULT}[what]
        if op is Op.MOVE and not (arg is not None and math.isfinite(arg) and abs(arg) < 2e5):
            raise ValueError(f"{self.name}: move_to({arg!r}) is not a rail position")
        if self._bus is None:
            if self._closed or not self._opened:
                raise LinkDown(self.name, "not open")
            async with self._relink:                # the last link died: try again (adapter replugged)
                if self._bus is None:
                    await self._connect()
        self._seq = self._seq % 255 + 1             # 1..255; 0 means "none yet" in status frames
        seq = self._seq
        fut = asyncio.get_running_loop().create_future()
        self._pending[seq] = (op, fut)
        msg = Command(op, seq, arg or 0.0, self.config.move_speed_m_s).to_message(self.config.node_id)
        try:
            with self._send_lock:
                self._bus.send(msg, timeout=self.config.command_timeout_s)
        except (can.CanError, OSError) as exc:
            self._on_link_error(exc)
            await asyncio.gather(fut, return_exceptions=True)
            raise LinkDown(self.name, f"cannot send {op.name}: {exc}") from None
        try:
            await asyncio.wait_for(fut, self.config.command_timeout_s)
        except TimeoutError:
            self._pending.pop(seq, None)
            raise DeviceTimeout(self.name, f"no reply to {op.name} (seq {seq}) in "
                                f"{self.config.command_timeout_s} s") from None

    def _silent_for(self) -> float:
        return time.monotonic() - self._last_rx

    def _status(self) -> RailStatus | None:
        if self._link_error is not None and self._opened:
            raise LinkDown(self.name, f"CAN link down: {self._link_error}")
        if self._silent_for() > self.config.status_timeout_s:
            raise DeviceTimeout(self.name, f"no status frame for {self._silent_for():.2f} s (CAN silence)")
        return self._latest

    async def _wait_until(self, predicate, timeout_s: float, stop_on_fault: bool = True) -> RailStatus:
        deadline = self.clock.now() + timeout_s
        since = time.monotonic()               # silence counts from our arrival at the earliest
        limit = self.config.status_timeout_s
        listened = False
        while True:
            if self._link_error is not None:
                raise LinkDown(self.name, f"CAN link down: {self._link_error}")
            quiet = time.monotonic() - max(self._last_rx, since)
            if quiet > limit and not listened:
                # A last listen before calling it silent: after a stall of this process the timer
                # can fire before the bus reader's thread has handed the loop the frames it holds.
                listened = True
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._changed.wait(), LAST_LISTEN_S)
                continue
            if quiet > limit:
                raise DeviceTimeout(self.name, f"no status frame for {quiet:.2f} s (CAN silence)")
            listened = False
            st = self._latest if self._silent_for() <= limit else None    # never judge a stale report
            if st is not None and predicate(st):
                return st
            if stop_on_fault and st is not None and st.state in ("fault", "estop"):
                raise DeviceFault(self.name, f"drive in {st.state} (fault code {st.fault_code})")
            left = deadline - self.clock.now()
            if left <= 0:
                raise DeviceTimeout(self.name, f"condition not met in {timeout_s} s; last {st}")
            # Wake on the next status frame; never sleep past the silence limit or the deadline.
            # A ManualClock's wall() is 0: then only frames (and the silence limit) wake us.
            nap = limit - quiet + 1e-3
            if self.clock.wall(left) > 0:
                nap = min(nap, self.clock.wall(left))
            try:
                await asyncio.wait_for(self._changed.wait(), max(nap, 1e-3))
            except TimeoutError:
                pass
