"""The thruster controller's ASCII line protocol: frames both ways, encoded and parsed.

Shared by the driver (devices/thrusters/serial_thrusters.py) and the simulated controller
(devices/sim/thrusters.py), so the two cannot drift apart. NMEA-style lines, as the contact
hub's: ``$<body>*HH\\r\\n`` with ``HH`` the XOR of the body's bytes. README "Thrusters line
protocol" is the reference; in short::

    controller -> device                      device -> controller
    $D,<seq>,<left>,<right>   drive           $A,<seq>,<result>                          reply
    $S,<seq>                  stop            $T,<seq>,<t_ms>,<left>,<right>,<flags>,<fault>  status
    $E,<seq>                  e-stop latch
    $R,<seq>                  reset latch
    $W,<seq>,<ms>             set watchdog

Thrust is signed per-mille of full thrust (-1000..1000, + forward). ``seq`` is 0..65535.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from enum import IntEnum
from functools import reduce
from operator import xor

MAX_LINE = 96
FULL = 1000                         # per-mille of full thrust on the wire
WATCHDOG_MS = (50, 600_000)         # the range a W command may set

FLAG_ESTOP, FLAG_WATCHDOG, FLAG_FAULT = 1, 2, 4


class Result(IntEnum):
    """Result field of a reply ``$A``: why the device refused a command."""

    ACCEPTED = 0
    ESTOP = 1           # drive refused: the e-stop latch is set (until R)
    FAULT = 2           # drive refused: the controller is in fault (until R)
    BAD_VALUE = 3       # thrust beyond +-1000, watchdog out of range
    BAD_COMMAND = 4     # unknown command letter, wrong field count


class Fault(IntEnum):
    NONE = 0
    OVERCURRENT = 1
    STALL = 2           # a propeller blocked (weed, a net)
    OVERTEMP = 3
    LEAK = 4            # water in the motor housing


def fault_name(code: int) -> str | None:
    if code == 0:
        return None
    try:
        return Fault(code).name.lower()
    except ValueError:
        return f"fault {code}"


def checksum(body: bytes) -> int:
    return reduce(xor, body, 0)


def frame(body: str) -> bytes:
    raw = body.encode()
    return b"$%s*%02X\r\n" % (raw, checksum(raw))


def per_mille(x: float) -> int:
    return round(x * FULL)


# --- controller -> device ---------------------------------------------------------------------
def drive_line(seq: int, left: float, right: float) -> bytes:
    return frame(f"D,{seq % 65536},{per_mille(left)},{per_mille(right)}")


def stop_line(seq: int) -> bytes:
    return frame(f"S,{seq % 65536}")


def estop_line(seq: int) -> bytes:
    return frame(f"E,{seq % 65536}")


def reset_line(seq: int) -> bytes:
    return frame(f"R,{seq % 65536}")


def watchdog_line(seq: int, watchdog_s: float) -> bytes:
    return frame(f"W,{seq % 65536},{round(watchdog_s * 1000)}")


# --- device -> controller ---------------------------------------------------------------------
def reply_line(seq: int, result: int) -> bytes:
    return frame(f"A,{seq % 65536},{int(result)}")


@dataclass(frozen=True, slots=True)
class Status:
    seq: int            # last accepted command's seq
    t: float            # the device's farm time, s
    left: float         # actual thrust, fraction of full
    right: float
    flags: int
    fault: int

    @property
    def estop(self) -> bool:
        return bool(self.flags & FLAG_ESTOP)

    @property
    def watchdog(self) -> bool:
        return bool(self.flags & FLAG_WATCHDOG)


def status_line(st: Status) -> bytes:
    return frame(f"T,{st.seq % 65536},{round(st.t * 1000)},{per_mille(st.left)},{per_mille(st.right)},"
                 f"{st.flags},{st.fault}")


# --- parsing ----------------------------------------------------------------------------------
class Lines:
    """Bytes in as they come, whole lines out. A run with no newline for longer than a line can be
    is line noise: dropped, and counted in ``torn``."""

    def __init__(self):
        self.partial = b""
        self.torn = 0

    def feed(self, data: bytes) -> list[bytes]:
        lines = (self.partial + data).split(b"\n")
        self.partial = lines.pop()
        if len(self.partial) > MAX_LINE:
            self.partial = b""
            self.torn += 1
        return lines


_LINE = re.compile(rb"\$([A-Z](?:,-?\d{1,16})*)\*([0-9A-F]{2})")
_FIELDS = {b"D": 3, b"S": 1, b"E": 1, b"R": 1, b"W": 2, b"A": 2, b"T": 6}


@dataclass(frozen=True, slots=True)
class Line:
    kind: str           # one letter
    fields: tuple[int, ...]


def parse(raw: bytes) -> Line | None:
    """One line (without ``\\r\\n``) as letter and integer fields; None for line noise: no
    frame, a wrong checksum, an unknown letter or the wrong number of fields."""
    m = _LINE.fullmatch(raw.rstrip(b"\r"))
    if m is None or int(m[2], 16) != checksum(m[1]):
        return None
    parts = m[1].split(b",")
    if _FIELDS.get(parts[0]) != len(parts) - 1:
        return None
    return Line(parts[0].decode(), tuple(int(p) for p in parts[1:]))


def parse_status(line: Line) -> Status | None:
    seq, t_ms, left, right, flags, fault = line.fields
    if not (0 <= seq < 65536 and abs(left) <= FULL and abs(right) <= FULL and 0 <= flags < 8 and fault >= 0):
        return None
    return Status(seq, t_ms / 1000.0, left / FULL, right / FULL, flags, fault)


def thrust_ok(x: float) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x) and -1.0 <= x <= 1.0
