"""A farm clock that runs fast while the whole farm is idle, shared through a memory-mapped file.

Farm time is piecewise linear in wall time. The file holds the current *segment*: from
``(wall0, farm0)`` farm time runs at ``speed`` until it reaches ``limit``, then at ``after`` (the
slow speed). The fallback is part of the segment, so the clock slows at the limit by itself, with
no process polling for it: the lookahead is exact in farm time whatever the machine's load.

Every process of one farm (the controller, the simulator) holds a *slot* and declares in it either
``busy`` (at most S x now: a carriage moving, a demand pending, fish asking) or ``idle until``
farm time T (the next episode start, the next survey). Whoever changes its slot re-governs the
segment under an exclusive ``flock`` on the file: the slowest busy speed if anyone is busy, else
``fast`` up to min(T) then ``slow``. A new segment starts at the farm time the old one gives at
that instant, so farm time is continuous. Slots that are awaited (reserved by the harness before
their process starts) or whose process has died count as busy at the slow speed: slow is always
safe, fast needs everyone's word.

Readers never lock: the segment sits under a sequence counter (odd while being written; a reader
retries until it reads the same even value before and after). A reader that read the old segment
an instant after the writer's anchor could run ahead of the new one by microseconds of ``fast``,
so ``now()`` is also held monotonic within a process.

Sleepers: a wake that falls inside the current segment's fast part is exact (a later segment can
only slow it, which wakes the sleeper early and it looks again); any other wake is slept in slices
of ``SLICE_S`` wall, as the speed may rise meanwhile (overshoot at most SLICE_S x fast). While the
farm runs fast nobody needs fine time, so naps are at least ``FAST_NAP_S`` of wall then (5 ms, the
slow slice's length: no later a wake than a slice already is): periodic farm-second ticks
(housekeeping every 5 farm s, the idle robot's look every 30) do not become busy loops at 30,000x.
"""
from __future__ import annotations

import asyncio
import fcntl
import math
import mmap
import os
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from devices.clock import iso

MAGIC = b"FFCK"
VERSION = 1
# magic, version, sequence counter, the segment (wall0, farm0, speed, limit, after), slow, fast, slots
HEAD = struct.Struct("<4sIQdddddddI4x")
SLOT = struct.Struct("<16siId16s")           # name, pid, kind, value, why (for the record)
NSLOTS = 16
SLICE_S = 0.005                              # wall: a sleeper's longest nap while the speed may rise
FAST_NAP_S = 0.005                           # wall: a sleeper's shortest nap while the farm runs fast: at
                                             # 1 ms the idle robot's look (ledger queries) and housekeeping
                                             # ran 1,000 times a wall second each, more of the controller's
                                             # CPU than the contacts of a fast span; no longer than SLICE_S
EMPTY, BUSY, IDLE, AWAITED = 0, 1, 2, 3
GEN_AT = 8                                   # byte offset of the sequence counter
SEG_AT = 16                                  # byte offset of the segment (5 doubles)
SEG = struct.Struct("<ddddd")


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


def create(path: str | Path, *, slow: float, fast: float, farm_start: float,
           awaited: tuple[str, ...] = (), wall_time: Callable[[], float] = time.time) -> None:
    """A new clock file at ``path``: farm time ``farm_start`` now, running at ``slow`` until the
    ``awaited`` slots' processes declare themselves."""
    if not 0 < slow <= fast:
        raise ValueError(f"clock speeds: need 0 < slow <= fast, got slow={slow} fast={fast}")
    buf = bytearray(HEAD.size + NSLOTS * SLOT.size)
    HEAD.pack_into(buf, 0, MAGIC, VERSION, 0, wall_time(), farm_start, slow, math.inf, slow, slow, fast, NSLOTS)
    for i, name in enumerate(awaited):
        SLOT.pack_into(buf, HEAD.size + i * SLOT.size, name.encode()[:16], 0, AWAITED, 0.0, b"awaited")
    tmp = Path(f"{path}.tmp")
    tmp.write_bytes(bytes(buf))
    os.replace(tmp, path)


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (one of another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class ElasticClock:
    """The clock interface of devices/clock.py (now, wall, sleep, asleep, iso, as_args) on a
    shared clock file, with ``claim`` / ``busy`` / ``idle_until`` for this process's slot."""

    def __init__(self, path: str | Path, wall_time: Callable[[], float] = time.time,
                 alive: Callable[[int], bool] = process_alive, pause: Callable[[float], None] = time.sleep):
        """``wall_time``, ``alive`` (is that pid running), ``pause`` (a blocking nap): injectable for tests."""
        self.path = str(path)
        self._time, self._alive, self._pause = wall_time, alive, pause
        self._fd = os.open(self.path, os.O_RDWR)
        size, need = os.fstat(self._fd).st_size, HEAD.size + NSLOTS * SLOT.size
        if size < need:             # (mmap's own complaint names neither the file nor the fault)
            os.close(self._fd)
            raise ValueError(f"{self.path}: not a fishfarm clock file ({size} bytes, a clock file has {need})")
        self._map = mmap.mmap(self._fd, need)
        magic, version, *_rest = HEAD.unpack_from(self._map, 0)
        if magic != MAGIC or version != VERSION:
            self.close()
            raise ValueError(f"{self.path}: not a fishfarm clock file (magic {magic!r}, version {version})")
        _m, _v, _g, *_seg, self.slow, self.fast, _n = HEAD.unpack_from(self._map, 0)
        self._last = -math.inf
        self._guard = threading.Lock()
        self.slot: int | None = None
        self._said: tuple[int, float] | None = None

    def close(self) -> None:
        self._map.close()
        os.close(self._fd)

    # -- reading ----------------------------------------------------------------------------
    def _read(self) -> tuple[Segment, float]:
        """The segment and a wall instant it holds at: the wall is read inside the sequence check,
        so a segment re-drawn after that instant (anchored later) cannot be mixed with it."""
        while True:
            g1 = struct.unpack_from("<Q", self._map, GEN_AT)[0]
            if g1 & 1:
                continue                       # a writer is in the middle: its write takes microseconds
            seg = SEG.unpack_from(self._map, SEG_AT)
            w = self._time()
            if struct.unpack_from("<Q", self._map, GEN_AT)[0] == g1:
                return Segment(*seg), w

    def segment(self) -> Segment:
        return self._read()[0]

    def now(self) -> float:
        seg, w = self._read()
        t = seg.farm_at(w)
        with self._guard:
            self._last = t = max(t, self._last)
        return t

    def at(self, wall: float) -> float:
        """Farm time at wall instant ``wall`` (a log record's, just made), on the current segment;
        an instant before the segment's anchor reads as the anchor (the earlier speed is gone)."""
        seg = self.segment()
        return seg.farm_at(max(wall, seg.wall0))

    @property
    def speed(self) -> float:
        seg, w = self._read()
        return seg.speed_at(seg.farm_at(w))

    def wall(self, farm_seconds: float) -> float:
        """Wall seconds ``farm_seconds`` take from now on the current segment; while the farm runs
        fast, at least ``FAST_NAP_S`` (a timeout of 30 farm s must not make a loop spin)."""
        seg, w = self._read()
        f = seg.farm_at(w)
        out = max(0.0, seg.wall_at(f + farm_seconds) - w)
        return max(out, FAST_NAP_S) if seg.speed_at(f) >= self.fast and farm_seconds > 0 else out

    def _nap(self, until: float) -> float | None:
        """Wall seconds to nap before looking again for farm time ``until``; None: it has come."""
        seg, w = self._read()
        if max(seg.farm_at(w), self._last) >= until:
            return None
        nap = max(0.0, seg.wall_at(until) - w)
        if seg.speed_at(seg.farm_at(w)) >= self.fast:
            # nobody needs fine time now: a 5-farm-s housekeeping tick is not a busy loop
            nap = max(nap, FAST_NAP_S)
        return nap if seg.speed_at(until) >= self.fast else min(nap, SLICE_S)

    def sleep(self, farm_seconds: float) -> None:
        until = self.now() + farm_seconds
        while (nap := self._nap(until)) is not None:
            self._pause(nap)

    async def asleep(self, farm_seconds: float) -> None:
        until = self.now() + max(0.0, farm_seconds)
        while (nap := self._nap(until)) is not None:
            await asyncio.sleep(nap)

    def iso(self, t: float | None = None) -> str:
        return iso(self.now() if t is None else t)

    def as_args(self) -> list[str]:
        return ["--clock", self.path]

    def slots(self) -> list[Slot]:
        out = []
        for i in range(NSLOTS):
            name, pid, kind, value, why = SLOT.unpack_from(self._map, HEAD.size + i * SLOT.size)
            out.append(Slot(name.rstrip(b"\0").decode(), pid, kind, value, why.rstrip(b"\0").decode()))
        return out

    # -- declaring ----------------------------------------------------------------------------
    def claim(self, name: str) -> int:
        """This process's slot ``name`` (an awaited one, one a dead process held, or a free one)."""
        with self._locked():
            slots = self.slots()
            mine = [i for i, s in enumerate(slots) if s.name == name and s.kind != EMPTY]
            free = [i for i, s in enumerate(slots) if s.kind == EMPTY]
            if not (mine or free):
                raise RuntimeError(f"{self.path}: all {NSLOTS} clock slots are taken")
            self.slot = (mine or free)[0]
            self._write_slot(name, BUSY, self.slow, "starting")
            self._govern()
        self._said = (BUSY, self.slow, "starting")
        return self.slot

    def busy(self, max_speed: float | None = None, why: str = "") -> None:
        """Farm time must run at no more than ``max_speed`` (default: the slow speed) from now."""
        self._declare(BUSY, min(self.slow if max_speed is None else max_speed, self.fast), why)

    def idle_until(self, t: float, why: str = "") -> None:
        """Nothing here needs fine time before farm time ``t``."""
        self._declare(IDLE, t, why)

    def release(self) -> None:
        """This process leaves the farm's timeline (its slot is freed)."""
        if self.slot is not None:
            with self._locked():
                self._write_slot("", EMPTY, 0.0, "")
                self._govern()
            self.slot, self._said = None, None

    def _declare(self, kind: int, value: float, why: str) -> None:
        if self.slot is None:
            raise RuntimeError("claim() a clock slot before declaring")
        if self._said == (kind, value, why):
            return                              # unchanged: the segment already says so
        with self._locked():
            self._write_slot(None, kind, value, why)
            self._govern()
        self._said = (kind, value, why)

    def govern(self) -> Segment:
        """Re-draw the segment from the slots now (the harness may call it; declaring does)."""
        with self._locked():
            return self._govern()

    def _govern(self) -> Segment:
        """Under the lock. The counter goes odd before the anchor's wall instant is read: a reader
        that got the old segment read its wall before that instant, where the old one holds."""
        old = self.segment()
        gen = struct.unpack_from("<Q", self._map, GEN_AT)[0]
        struct.pack_into("<Q", self._map, GEN_AT, gen + 1)
        try:
            w = self._time()
            f = max(old.farm_at(w), self._last)
            speed, limit = self._pace(f)
            if (old.speed, old.limit) == (speed, limit):
                return old
            new = Segment(w, f, speed, limit, self.slow)
            SEG.pack_into(self._map, SEG_AT, new.wall0, new.farm0, new.speed, new.limit, new.after)
            return new
        finally:
            struct.pack_into("<Q", self._map, GEN_AT, gen + 2)

    def _pace(self, f: float) -> tuple[float, float]:
        """(speed, limit) the slots ask for at farm time ``f``."""
        busy, until = [], []
        for s in self.slots():
            if s.kind == AWAITED or (s.kind in (BUSY, IDLE) and not self._alive(s.pid)):
                busy.append(self.slow)
            elif s.kind == BUSY:
                busy.append(s.value)
            elif s.kind == IDLE:
                until.append(s.value)
        if busy or not until:
            return min(busy, default=self.slow), math.inf
        limit = min(until)
        return (self.fast, limit) if limit > f else (self.slow, math.inf)

    def _write_slot(self, name: str | None, kind: int, value: float, why: str) -> None:
        at = HEAD.size + self.slot * SLOT.size
        if name is None:
            name = SLOT.unpack_from(self._map, at)[0].rstrip(b"\0").decode()
        SLOT.pack_into(self._map, at, name.encode()[:16], os.getpid() if kind != EMPTY else 0, kind, value,
                       why.encode()[:16])

    def _locked(self):
        return _Flock(self._fd)


class _Flock:
    def __init__(self, fd: int):
        self.fd = fd

    def __enter__(self):
        fcntl.flock(self.fd, fcntl.LOCK_EX)

    def __exit__(self, *exc):
        fcntl.flock(self.fd, fcntl.LOCK_UN)
