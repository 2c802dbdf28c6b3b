"""Frame ports for simulated CAN devices: a python-can bus, or the device side of an slcan adapter.

A frame port is the tiny surface a simulated drive needs to be on a bus:
``await start(receive)`` (``receive(msg)`` is then called on the asyncio loop for every frame
from the bus), ``send(msg)`` and ``await stop()``.

``SlcanAdapter`` plays a LAWICEL/slcan USB-CAN adapter on a pseudo-terminal: the controller opens
``adapter.port`` with python-can's ``slcan`` interface exactly as it would /dev/ttyACM0, and
the drive behind the adapter sees the frames. What the adapter answers (CR = ok, BEL = error):

    O / L      open the channel (normal / listen-only)        CR, BEL if already open
    C          close the channel                              CR, BEL if closed
    S0..S9     bitrate 10k..1M, 83.3k (channel closed)        CR, BEL if open or unknown
    sXXYY      BTR0/BTR1 bit timing (channel closed)          CR
    V / N      version / serial number                        V1013 CR / NSIM1 CR
    F          status flags (bit 3: data overrun)             Fxx CR, BEL if closed
    Z / M / m  timestamps, acceptance code/mask               CR (accepted, no effect)
    tiiiL..    transmit standard frame (T: extended 29-bit)   z CR (Z CR), BEL if closed/bad
    riiiL      remote frame (R: extended)                     z CR (Z CR)
    (empty)    a bare CR clears the adapter's command buffer  CR
    anything else                                             BEL

Frames from the bus go to the host as ``tiiiLdd..CR`` (``T``/``r``/``R`` alike) while the
channel is open; a full serial buffer drops them and sets the overrun flag, as an adapter does.
Only whole frames are dropped: when the pty takes part of one, the rest is kept (``backlog``)
and goes out first, as soon as the pty has room; anything new meanwhile is dropped whole.
"""
from __future__ import annotations

import asyncio
import logging
import os
import re
import tty
from collections.abc import Callable

import can

from devices.rail.can_drive import LinkNotifier

log = logging.getLogger(__name__)

_OK, _ERR = b"\r", b"\a"
_FRAME = re.compile(r"^(?:t([0-9A-F]{3})|T([0-9A-F]{8})|r([0-9A-F]{3})|R([0-9A-F]{8}))([0-8])([0-9A-F]*)$",
                    re.IGNORECASE)
_OVERRUN = 0x08
Receive = Callable[[can.Message], None]


class BusPort:
    """A python-can bus (the ``virtual`` bus in tests) as a frame port. Owns and shuts the bus."""

    def __init__(self, bus: can.BusABC):
        self.bus = bus
        self._notifier: LinkNotifier | None = None

    @classmethod
    def virtual(cls, channel: str) -> BusPort:
        return cls(can.Bus(interface="virtual", channel=channel))

    async def start(self, receive: Receive) -> None:
        self._notifier = LinkNotifier(self.bus, [receive], timeout=0.02, loop=asyncio.get_running_loop())

    def send(self, msg: can.Message) -> None:
        self.bus.send(msg, timeout=0.1)

    async def stop(self) -> None:
        if self._notifier is not None:
            self._notifier.stop(timeout=0.5)
            self._notifier = None
        self.bus.shutdown()


class SlcanAdapter:
    """The device side of an slcan adapter on a pty. ``port`` is the path the host opens."""

    def __init__(self, version: str = "1013", serial_number: str = "SIM1"):
        self.version = version
        self.serial_number = serial_number
        self.port: str | None = None
        self.is_open = False              # the CAN channel (O ... C), not the pty
        self.listen_only = False          # opened with L: hears the bus, may not transmit
        self.bitrate_code: str | None = None
        self._master = self._slave = -1
        self._buf = bytearray()
        self._backlog = b""               # the unsent tail of a frame or answer the pty took part of
        self._flags = 0
        self._receive: Receive | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    async def start(self, receive: Receive) -> None:
        self._receive = receive
        self._master, self._slave = os.openpty()
        # Raw line, and keep our own slave fd open: without it the master reads EIO until the
        # host opens the port, and whenever it closes it again.
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(self._master, self._on_readable)

    async def stop(self) -> None:
        """Unplug: the host's next read or write of the port fails (EIO)."""
        if self._master >= 0:
            self._loop.remove_reader(self._master)
            self._loop.remove_writer(self._master)
            os.close(self._master)
            os.close(self._slave)
            self._master = self._slave = -1
        self._backlog = b""
        self.is_open = False

    @property
    def backlog(self) -> int:
        """Bytes of a partly written frame still waiting for room in the pty."""
        return len(self._backlog)

    # --- bus -> host ----------------------------------------------------------------------------
    def send(self, msg: can.Message) -> None:
        if not self.is_open or self._master < 0:
            return                        # a closed channel forwards nothing
        if msg.is_extended_id:
            head = f"{'R' if msg.is_remote_frame else 'T'}{msg.arbitration_id:08X}{msg.dlc:d}"
        else:
            head = f"{'r' if msg.is_remote_frame else 't'}{msg.arbitration_id:03X}{msg.dlc:d}"
        body = "" if msg.is_remote_frame else bytes(msg.data).hex().upper()
        self._write((head + body).encode() + _OK)

    def _write(self, data: bytes) -> None:
        if self._master < 0:
            return
        if self._backlog:
            self._flush()
        if self._backlog:
            self._flags |= _OVERRUN       # host not reading: drop, as a full adapter FIFO does
            return
        self._backlog = data
        self._flush()

    def _flush(self) -> None:
        """Write the backlog, or as much as fits; watch for room while some is left."""
        try:
            n = os.write(self._master, self._backlog)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            log.debug("slcan adapter %s: write failed: %s", self.port, exc)
            n = len(self._backlog)
        # a frame half written must be finished before anything else, or the host sees garbage
        self._backlog = self._backlog[n:]
        if self._backlog:
            self._loop.add_writer(self._master, self._flush)
        else:
            self._loop.remove_writer(self._master)

    # --- host -> adapter ------------------------------------------------------------------------
    def _on_readable(self) -> None:
        try:
            chunk = os.read(self._master, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            log.debug("slcan adapter %s: read failed: %s", self.port, exc)
            return
        self._buf += chunk
        *lines, rest = self._buf.split(_OK)
        self._buf = bytearray(rest)
        for line in lines:
            self._write(self._answer(line.decode("ascii", "replace").strip("\n")))

    def _answer(self, line: str) -> bytes:
        if not line:
            return _OK
        cmd = line[0]
        if cmd in "tTrR":
            return self._transmit(line)
        if cmd in "OLC":
            return self._open_close(cmd)
        if cmd in "Ss":
            return self._bitrate(line)
        if cmd == "V":
            return f"V{self.version}".encode() + _OK
        if cmd == "N":
            return f"N{self.serial_number}".encode() + _OK
        if cmd == "F":
            if not self.is_open:
                return _ERR
            flags, self._flags = self._flags, 0
            return f"F{flags:02X}".encode() + _OK
        if cmd in "ZMm":
            return _OK
        return _ERR

    def _open_close(self, cmd: str) -> bytes:
        if self.is_open == (cmd != "C"):
            return _ERR
        self.is_open, self.listen_only = cmd != "C", cmd == "L"
        return _OK

    def _bitrate(self, line: str) -> bytes:
        if self.is_open:
            return _ERR
        ok = re.fullmatch(r"S[0-9]", line) or re.fullmatch(r"s[0-9A-Fa-f]{4}", line)
        if not ok:
            return _ERR
        self.bitrate_code = line
        return _OK

    def _transmit(self, line: str) -> bytes:
        m = _FRAME.match(line)
        if not self.is_open or self.listen_only or m is None:
            return _ERR
        std, ext, rstd, rext, dlc, data = m.groups()
        remote = rstd is not None or rext is not None
        dlc = int(dlc)
        if (not remote and len(data) != 2 * dlc) or (remote and data):
            return _ERR
        extended = ext is not None or rext is not None
        msg = can.Message(arbitration_id=int(std or ext or rstd or rext, 16), is_extended_id=extended,
                          is_remote_frame=remote, dlc=dlc, data=b"" if remote else bytes.fromhex(data))
        if self._receive is not None:
            self._receive(msg)
        return (b"Z" if extended else b"z") + _OK
