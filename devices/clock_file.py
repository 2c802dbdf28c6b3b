"""The elastic clock's file (devices/elastic_clock.py): its layout, the bounds of what it may hold, and
the checks of what is read from it.

A clock file is shared by every process of one farm and written by all of them, so what is read is
checked, not trusted: a file cut short is mapped past its end (SIGBUS kills the reader, with no
line said), a speed of 0 divides by zero, a NaN farm time or one past the year 9999 breaks every
log line, a slot name that is not UTF-8 breaks every re-draw. Each fault is named by the file and
the field (``BadInput``, one line, exit 2).
"""
from __future__ import annotations

import fcntl
import math
import os
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from devices.errors import BadInput

MAGIC = b"FFCK"
VERSION = 2                                  # 2: each slot's word carries the wall instant it was last given
# magic, version, sequence counter, the segment (wall0, farm0, speed, limit, after), slow, fast, slots,
# the lease of a word (wall s; 0: words hold until changed)
HEAD = struct.Struct("<4sIQdddddddI4xd")
SLOT = struct.Struct("<16siId16sd")          # name, pid, kind, value, why (for the record), seen (wall)
NSLOTS = 16
SIZE = HEAD.size + NSLOTS * SLOT.size        # 984 bytes
EMPTY, BUSY, IDLE, AWAITED = 0, 1, 2, 3
KINDS = (EMPTY, BUSY, IDLE, AWAITED)
GEN_AT = 8                                   # byte offset of the sequence counter
SEG_AT = 16                                  # byte offset of the segment (5 doubles)
SEG = struct.Struct("<ddddd")
SLOTS = ("sim", "controller")                # the names the farm's processes claim (fishfarm sim, run)

# every farm instant is a date the clock can print and the ledger holds: before 2000 is a typo
# (`--farm-start 0`), from 2200 on the clock's arithmetic reaches past the year 9999 within a run
FARM_MIN = 946_684_800.0                     # 2000-01-01T00:00:00Z
FARM_MAX = 7_258_118_400.0                   # 2200-01-01T00:00:00Z
FARM_SANE = 9.5e10                           # ~year 5000: a segment past it is garbage; one past FARM_MAX
                                             # is a farm that ran on (1e6x from 2199: 86 wall s), not mended
                                             # at every read
LEASE_S = 0.02                               # wall: how long a process's word holds without being given again
MAX_LEASE_S = 60.0
CRAWL = 0.1                                  # the share of its speed the farm runs at once a word has lapsed
MAX_SPEED = 1e6                              # farm s per wall s (a farm year in ~30 s of wall)
WALL_AHEAD_S = 5.0                           # a segment anchored further in the wall's future is not a writer's


@dataclass(frozen=True)
class Segment:
    wall0: float
    farm0: float
    speed: float
    limit: float          # farm time where ``speed`` gives way to ``after``
    after: float

    def farm_at(self, wall: float) -> float:
        f = self.farm0 + (wall - self.wall0) * self.speed
        if f <= self.limit:
            return f
        return self.limit + (wall - self.limit_wall()) * self.after

    def limit_wall(self) -> float:
        return self.wall0 + (self.limit - self.farm0) / self.speed

    def wall_at(self, farm: float) -> float:
        """The wall instant this segment reaches farm time ``farm``."""
        if farm <= self.limit:
            return self.wall0 + (farm - self.farm0) / self.speed
        return self.limit_wall() + (farm - self.limit) / self.after

    def speed_at(self, farm: float) -> float:
        return self.speed if farm <= self.limit else self.after


@dataclass(frozen=True)
class Slot:
    name: str
    pid: int
    kind: int
    value: float
    why: str = ""
    seen: float = 0.0     # wall instant the holder last gave its word (its lease: devices/elastic_clock.py)


def in_farm_range(t: float) -> bool:
    return FARM_MIN <= t < FARM_MAX


def farm_range_fault(t: float) -> str | None:
    """Why ``t`` cannot be a farm instant, or None."""
    if in_farm_range(t):
        return None
    return f"{t!r} is outside the farm's years 2000-2199 (Unix s {FARM_MIN:.0f} to {FARM_MAX:.0f})"


def speed_fault(s: float) -> str | None:
    if math.isfinite(s) and 0 < s <= MAX_SPEED:
        return None
    return f"{s!r}: a speed must be > 0 and at most {MAX_SPEED:g}"


def lease_fault(lease: float) -> str | None:
    if math.isfinite(lease) and 0 <= lease <= MAX_LEASE_S:
        return None
    return f"{lease!r} s: a lease is 0 (none) to {MAX_LEASE_S:g} s"


def speeds_fault(slow: float, fast: float) -> tuple[str, str] | None:
    """(field, fault) of a bad pair of speeds, or None."""
    for name, value in (("slow", slow), ("fast", fast)):
        if (fault := speed_fault(value)) is not None:
            return name, fault
    if slow > fast:
        return "slow", f"{slow:g} is faster than fast {fast:g}"
    return None


def segment_fault(seg: Segment, wall: float, fast: float) -> str | None:
    """What is wrong with ``seg`` read at wall instant ``wall`` (None: nothing)."""
    if not all(math.isfinite(v) for v in (seg.wall0, seg.farm0, seg.speed, seg.after)) or math.isnan(seg.limit):
        return "not a number"
    if not (0 < seg.speed <= fast and 0 < seg.after <= fast):
        return f"speed {seg.speed!r} then {seg.after!r}: not in (0, fast {fast:g}]"
    if not FARM_MIN <= seg.farm0 < FARM_SANE:
        return f"farm time {seg.farm0!r} outside the years 2000-5000"
    if seg.limit < seg.farm0:
        return f"limit {seg.limit!r} before its start {seg.farm0!r}"
    if seg.wall0 > wall + WALL_AHEAD_S:
        return f"anchored {seg.wall0 - wall:.0f} s in the wall clock's future"
    return None


def slot_fault(raw: tuple, fast: float, wall: float | None = None) -> str | None:
    """What is wrong with a slot as unpacked from the file (None: nothing); with ``wall``, a word
    given further in the wall's future than a segment may be anchored (its lease never lapsed)."""
    name, pid, kind, value, why, seen = raw
    if kind not in KINDS:
        return f"kind {kind} (0 to 3)"
    if kind == EMPTY:
        return None
    try:
        name.rstrip(b"\0").decode()
        why.rstrip(b"\0").decode()
    except UnicodeDecodeError:
        return "name or word not UTF-8"
    if kind == BUSY and not (math.isfinite(value) and 0 < value <= fast):
        return f"busy at {value!r}: not in (0, fast {fast:g}]"
    if kind == IDLE and not (math.isfinite(value) and value < FARM_MAX):
        return f"idle until {value!r}: not a farm time before 2200"
    if kind != AWAITED and pid <= 0:
        return f"pid {pid}"
    if kind != AWAITED and not (math.isfinite(seen) and seen >= 0):
        return f"word seen at {seen!r}: not a wall instant"
    if kind != AWAITED and wall is not None and seen > wall + WALL_AHEAD_S:
        return f"word seen {seen - wall:.0f} s in the wall clock's future"
    return None


def pace_of(raws: list[tuple], f: float, w: float, slow: float, fast: float,
            alive: Callable[[int], bool], lease_s: float) -> tuple[float, float, float]:
    """(speed, limit, after) of the segment the slots (as unpacked) ask for at farm time ``f``, wall
    instant ``w``: the slowest busy speed if anyone is busy, else ``fast`` up to the earliest idle
    word's farm time, then ``slow``. A spoilt slot, an awaited one and a dead holder's are busy at
    ``slow`` (a zombie is dead: ``process_alive``, ~8 us a holder). Every live word is a lease of
    ``lease_s`` wall from when it was given (0: none): the segment's speed holds until the first
    lapses, then the farm crawls (a ``CRAWL`` of the slow speed, or of the busy one), so farm time
    waits for a process that stopped running (descheduled on a loaded machine, or stuck) instead of
    running on without it, hours of it at the fast speed."""
    busy, until, lease = [], [], math.inf
    for raw in raws:
        if slot_fault(raw, fast, w) is not None:
            busy.append(slow)                  # a slot spoilt since the file was opened: its word is none
            continue
        s = decode_slot(raw)
        if s.kind == AWAITED or (s.kind in (BUSY, IDLE) and not alive(s.pid)):
            busy.append(slow)
            continue
        if s.kind in (BUSY, IDLE) and lease_s > 0:
            lease = min(lease, s.seen + lease_s)
        if s.kind == BUSY:
            busy.append(s.value)
        elif s.kind == IDLE:
            until.append(s.value)
    speed = min(busy, default=slow) if busy or not until else fast if min(until) > f else slow
    if lease <= w:                             # a word lapsed already: crawl now
        return speed * CRAWL if speed < fast else slow * CRAWL, math.inf, slow
    held = math.inf if math.isinf(lease) else f + (lease - w) * speed
    first = min(until, default=math.inf)
    if speed >= fast and first <= held:
        return speed, first, slow              # the lookahead's slow-down comes first
    return speed, held, (slow if speed >= fast else speed) * CRAWL if math.isfinite(held) else slow


def decode_slot(raw: tuple) -> Slot:
    name, pid, kind, value, why, seen = raw
    return Slot(name.rstrip(b"\0").decode(errors="replace"), pid, kind, value,
                why.rstrip(b"\0").decode(errors="replace"), seen)


def check_file(path: str, buf, wall: float | None = None) -> tuple[float, float, float]:
    """(slow, fast, lease) of the clock file whose first SIZE bytes are ``buf``; BadInput naming the
    field at fault. The segment is checked by the reader (a dead writer's may be re-drawn)."""
    magic, version, _gen, *_seg, slow, fast, nslots, lease = HEAD.unpack_from(buf, 0)
    if magic != MAGIC or version != VERSION:
        raise BadInput(path, None, f"not a fishfarm clock file (magic {magic!r}, version {version})")
    if nslots != NSLOTS:
        raise BadInput(path, "slots", f"{nslots}: a clock file has {NSLOTS}")
    if (bad := speeds_fault(slow, fast)) is not None:
        raise BadInput(path, *bad)
    if (fault := lease_fault(lease)) is not None:
        raise BadInput(path, "lease", fault)
    for i in range(NSLOTS):
        if (fault := slot_fault(SLOT.unpack_from(buf, HEAD.size + i * SLOT.size), fast, wall)) is not None:
            raise BadInput(path, f"slot {i}", fault)
    return slow, fast, lease


def is_clock_file(path: str | Path) -> bool:
    """Whether ``path`` starts as a clock file does (its magic and version)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError:
        return False
    return len(head) == 8 and struct.unpack("<4sI", head) == (MAGIC, VERSION)


def layout(*, slow: float, fast: float, farm_start: float, awaited: tuple[str, ...] = (),
           wall: float, lease_s: float = LEASE_S) -> bytes:
    """The bytes of a new clock file: farm time ``farm_start`` at wall instant ``wall``, running
    at ``slow`` until the ``awaited`` slots' processes declare themselves. ValueError naming the fault."""
    if (bad := speeds_fault(slow, fast)) is not None:
        raise ValueError(f"clock speeds: {bad[0]}: {bad[1]}")
    if (fault := farm_range_fault(farm_start)) is not None:
        raise ValueError(f"farm start: {fault}")
    if (fault := lease_fault(lease_s)) is not None:
        raise ValueError(f"lease: {fault}")
    if len(awaited) > NSLOTS or len(set(awaited)) != len(awaited) \
            or any(not n or len(n.encode()) > 16 for n in awaited):
        raise ValueError(f"awaited slots {awaited!r}: at most {NSLOTS} different names of 1 to 16 bytes")
    buf = bytearray(SIZE)
    HEAD.pack_into(buf, 0, MAGIC, VERSION, 0, wall, farm_start, slow, math.inf, slow, slow, fast, NSLOTS, lease_s)
    for i, name in enumerate(awaited):
        SLOT.pack_into(buf, HEAD.size + i * SLOT.size, name.encode(), 0, AWAITED, 0.0, b"awaited", 0.0)
    return bytes(buf)


def create(path: str | Path, *, slow: float, fast: float, farm_start: float,
           awaited: tuple[str, ...] = (), wall_time: Callable[[], float] = time.time, lease_s: float = LEASE_S) -> None:
    """A new clock file at ``path`` (see ``layout``), written whole beside it and renamed into place."""
    data = layout(slow=slow, fast=fast, farm_start=farm_start, awaited=awaited, wall=wall_time(), lease_s=lease_s)
    tmp = Path(f"{path}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs (one of another user's counts; a zombie, killed and not yet
    reaped by its parent, does not: its lapsed word read as a live one stopped, a crawl)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except (OSError, IndexError):
        return True                            # (no /proc to ask: it exists)


class Flock:
    """The file's exclusive flock, and this process's writer lock with it: the flock is the open
    file's, so a reader in this process could take it while another thread of it writes."""

    def __init__(self, fd: int, wlock: threading.Lock):
        self.fd, self.wlock = fd, wlock

    def __enter__(self):
        self.wlock.acquire()
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX)
        except BaseException:
            self.wlock.release()
            raise

    def __exit__(self, *exc):
        try:
            fcntl.flock(self.fd, fcntl.LOCK_UN)
        finally:
            self.wlock.release()


def utf8_16(text: str) -> bytes:
    """At most 16 bytes of ``text``, cut between characters (a cut one is no UTF-8: a spoilt slot)."""
    return text.encode()[:16].decode(errors="ignore").encode()
