"""The contact hub on a serial line (pyserial): one ASCII line per contact, NMEA-style.

Line protocol (hub -> controller; 8N1, default 115200 baud; the hub never listens)::

    $C,<seq>,<sensor>,<t_ms>*HH\\r\\n     a contact (rising edge) of <sensor> at farm time t_ms
    $H,<seq>,<t_ms>*HH\\r\\n              heartbeat, at least once a second, contacts or not

- ``seq``: decimal 0..65535, +1 per line of either kind, wrapping; a jump means lines were lost
  (counted in ``lost``, never fatal: the filter copes with a missing contact).
- ``sensor``: 1–32 of ``A-Z a-z 0-9 _ -``.  ``t_ms``: the hub's clock, Unix milliseconds.
- ``HH``: two upper-case hex digits, XOR of every byte between ``$`` and ``*`` (NMEA 0183).

A line that does not parse or whose checksum is wrong is line noise: counted in ``malformed``
and skipped. Silence means a dead line, not calm fish (the heartbeat says so): no valid line for
``silence_timeout_s`` wall seconds raises LinkDown, as does the port vanishing (EIO/EOF on a
pseudo-terminal whose other side is gone, a USB adapter unplugged). The port is read on the
asyncio loop with ``add_reader`` (no thread): each readable event drains what the kernel holds.
"""
from __future__ import annotations

import asyncio
import errno
import os
import re
import select
from functools import reduce
from operator import xor

import serial
from pydantic import Field, field_validator

from devices.base import Section
from devices.contacts import Contact, ContactSensors
from devices.errors import LinkDown

LINE = re.compile(rb"\$(C,(\d{1,5}),([A-Za-z0-9_-]{1,32}),(\d{1,16})|H,(\d{1,5}),(\d{1,16}))\*([0-9A-F]{2})")
MAX_LINE = 128


def checksum(body: bytes) -> int:
    return reduce(xor, body, 0)


def contact_line(seq: int, sensor: str, t: float) -> bytes:
    body = f"C,{seq % 65536},{sensor},{round(t * 1000)}".encode()
    return b"$%s*%02X\r\n" % (body, checksum(body))


def heartbeat_line(seq: int, t: float) -> bytes:
    body = f"H,{seq % 65536},{round(t * 1000)}".encode()
    return b"$%s*%02X\r\n" % (body, checksum(body))


class Config(Section):
    port: str = Field(min_length=1, description="serial device (/dev/ttyUSB0, a pty), or a pyserial URL backed by a "
                                  "file descriptor (socket://, hwgrep://); not loop:// or rfc2217://")
    baudrate: int = Field(115200, gt=0)
    silence_timeout_s: float = Field(3.0, gt=0, description="wall seconds without a valid line")

    @field_validator("port")
    @classmethod
    def _has_a_descriptor(cls, port: str) -> str:
        # the reader waits on the port's file descriptor: these URLs have none (the controller
        # started, then alarmed and retried them for good)
        scheme = port.split("://", 1)[0].lower() if "://" in port else None
        if scheme in ("loop", "rfc2217", "cp2110"):
            raise ValueError(f"{scheme}:// has no file descriptor to wait on: give a device path, "
                             "socket:// or hwgrep://")
        return port


class SerialContactHub(ContactSensors):
    Config = Config

    def __init__(self, name: str, config: Config, clock):
        super().__init__(name, config, clock)
        self.malformed = 0                  # lines rejected (noise, bad checksum)
        self.lost = 0                       # lines missing by sequence number
        self._greeted = False               # read() has told its caller the line is heard
        self.lines = 0                      # valid lines
        self._ser: serial.Serial | None = None
        self._fd = -1
        self._partial = b""
        self._batch: list[Contact] = []
        self._parsed_t: float | None = None  # the newest stamp parsed (``stream_t`` once read)
        self._error: str | None = None
        self._seq: int | None = None
        self._wake = asyncio.Event()
        self._last_line = 0.0

    async def _open(self) -> None:
        try:
            # exclusive: a port another process reads (devices.serial_lock) is refused, not shared
            self._ser = serial.serial_for_url(self.config.port, baudrate=self.config.baudrate, timeout=0,
                                              exclusive=True)
            self._ser.reset_input_buffer()            # stale lines from before we listened
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkDown(self.name, f"cannot open {self.config.port}: {exc}") from None
        # The port is watched by the loop (add_reader), so it needs a file descriptor: a device
        # path or socket:// has one, loop:// and rfc2217:// do not. Device.open closes the port.
        try:
            fd = self._ser.fileno()
        except (OSError, ValueError, AttributeError) as exc:
            raise LinkDown(self.name, f"cannot use {self.config.port}: no file descriptor to watch "
                                      f"({type(exc).__name__}: {exc})") from None
        loop = asyncio.get_running_loop()
        try:
            loop.add_reader(fd, self._readable)
        except (OSError, ValueError) as exc:
            raise LinkDown(self.name, f"cannot watch {self.config.port}: {exc}") from None
        self._fd = fd
        self._last_line = loop.time()

    async def _close(self) -> None:
        if self._fd >= 0:
            asyncio.get_running_loop().remove_reader(self._fd)
            self._fd = -1
        if self._ser is not None:
            self._ser.close()
            self._ser = None

    async def _read(self) -> list[Contact]:
        loop = asyncio.get_running_loop()
        timeout = self.config.silence_timeout_s
        # the first good line heard returns, contacts or none: a heartbeat says the line is back
        # (its loss alarm stood until a fish bumped a sensor: at night, for hours)
        while not self._batch and (self._greeted or not self.lines):
            if self._error is not None:
                raise LinkDown(self.name, self._error)
            left = self._last_line + timeout - loop.time()
            if left <= 0:
                # A last look at the port itself before calling it silent: after a stall of this
                # process (a VM descheduled, a long GC) the timer may fire before the loop has run
                # the port's reader, with the hub's lines waiting unread in the kernel.
                if self._fd >= 0 and select.select([self._fd], [], [], 0)[0]:
                    self._readable()      # ready: an empty read is the port gone, as on the loop
                if self._batch or self._error is not None or loop.time() < self._last_line + timeout:
                    continue
                raise LinkDown(self.name, f"{self.config.port} silent for {timeout:g} s (no heartbeat)")
            self._wake.clear()
            # asyncio.wait, not wait_for: on Python 3.11 wait_for swallows a cancel that lands in
            # the same loop turn as the wake-up (gh-86296), and a stopping controller hangs on it
            waiter = asyncio.ensure_future(self._wake.wait())
            try:
                await asyncio.wait({waiter}, timeout=left)
            finally:
                waiter.cancel()
        out, self._batch = self._batch, []
        self._greeted = True
        self._heard_up_to(self._parsed_t)          # the reader has every contact up to there now
        return out

    def _heard_up_to(self, t: float | None) -> None:
        if t is not None and (self.stream_t is None or t > self.stream_t):
            self.stream_t = t

    # -- on the loop, when the port has bytes -----------------------------------------------------
    def _readable(self) -> None:
        try:
            data = os.read(self._fd, 65536)
        except BlockingIOError:
            return
        except OSError as exc:
            gone = exc.errno in (errno.EIO, errno.ENXIO, errno.EBADF, errno.ENODEV)
            return self._down(f"{self.config.port}: {'port gone' if gone else exc.strerror}")
        if not data:
            return self._down(f"{self.config.port}: end of file (port gone)")
        lines = (self._partial + data).split(b"\n")
        self._partial = lines.pop()
        if len(self._partial) > MAX_LINE:           # no newline for too long: noise
            self._partial = b""
            self.malformed += 1
        if self._parse(lines):
            self._last_line = asyncio.get_running_loop().time()
            self._wake.set()

    def _parse(self, lines: list[bytes]) -> bool:
        good = False
        batch = self._batch
        for raw in lines:
            m = LINE.fullmatch(raw.rstrip(b"\r"))
            if m is None or int(m[7], 16) != checksum(m[1]) or int(m[2] or m[5]) > 65535:   # seq: 0..65535
                if raw.strip():
                    self.malformed += 1
                continue
            good = True
            self.lines += 1
            seq = int(m[2] or m[5])
            if self._seq is not None:
                self.lost += (seq - self._seq - 1) % 65536
            self._seq = seq
            t = int(m[4] or m[6]) / 1000.0
            if m[3] is not None:
                batch.append(Contact(t, m[3].decode()))
            if self._parsed_t is None or t > self._parsed_t:
                self._parsed_t = t
        if not batch:
            # only heartbeats: nothing waits to be read. Contacts waiting hold ``stream_t`` back
            # until read() hands them out: a filter judging time up to a stamp parsed past them
            # would close their bins first and count them all in a later one (on a fast farm
            # clock, a batch of hundreds of farm seconds of turbulence in one bin: a false demand)
            self._heard_up_to(self._parsed_t)
        return good

    def _down(self, why: str) -> None:
        self._error = why
        if self._fd >= 0:
            asyncio.get_running_loop().remove_reader(self._fd)
            self._fd = -1
        self._wake.set()
