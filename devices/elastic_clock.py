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

A word is a lease of the file's ``lease_s`` of wall (``clock_file.pace_of``): given again every
``RENEW_SHARE`` of it while unchanged, and the segment's speed holds only until the oldest live
word lapses (then the farm crawls: a tenth of the slow speed, or of a busy word's; a segment every
holder left is drawn again by a reader, clock_reading.py). A process that stopped running
(descheduled on a loaded machine) stops the farm running on without it: it had read nothing for
0.9 s of wall while the farm ran nine hours fast, and heard the next meal's fish minutes late.

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
import bisect
import logging
import math
import mmap
import os
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

from devices.clock import iso
from devices.clock_file import (  # noqa: F401  (the names users of the clock import from here)
    AWAITED,
    BUSY,
    EMPTY,
    FARM_MAX,
    GEN_AT,
    HEAD,
    IDLE,
    NSLOTS,
    SEG,
    SEG_AT,
    SIZE,
    SLOT,
    Flock,
    Segment,
    Slot,
    check_file,
    create,
    decode_slot,
    pace_of,
    process_alive,
    segment_fault,
    slot_fault,
    utf8_16,
)
from devices.clock_reading import SegmentReading
from devices.errors import BadInput

SLICE_S = 0.005                              # wall: a sleeper's longest nap while the speed may rise
FAST_NAP_S = 0.005                           # wall: a sleeper's shortest nap while the farm runs fast: at
                                             # 1 ms the idle robot's look (ledger queries) and housekeeping
                                             # ran 1,000 times a wall second each, more of the controller's
                                             # CPU than the contacts of a fast span; no longer than SLICE_S
CLAIM_WAIT_S = 3.0                           # wall: a slot's live holder is waited for this long (the
                                             # simulator's stop takes at most 1 s) before claim refuses
RENEW_SHARE = 0.2                            # a word unchanged is given again after this share of its lease
                                             # (the pacers look every 5 ms): one late look does not end it
ALIVE_TTL_S = 0.1                            # wall: a holder found running is not asked again for this long
SEEN_EVERY_S = 0.05                          # wall: readings kept for wall_since, at most this often...
SEEN_N = 1200                                # ... for a minute
log = logging.getLogger("fishfarm.clock")


class RecentlyAlive:
    """``ask(pid)`` (``process_alive``), a pid found running taken as running for ``ttl_s`` of wall
    without asking again. A renewal (every 4 ms a process) redraws the segment from every slot, and
    asking the kernel and reading /proc/PID/stat for each live holder was ~60 % of its cost (~70 us
    of ~115). A holder's death is seen up to ``ttl_s`` late: its lapsed lease a crawl that long, not
    the slow speed a dead holder's word gets."""

    def __init__(self, ask: Callable[[int], bool] = process_alive, ttl_s: float = ALIVE_TTL_S,
                 now: Callable[[], float] = time.monotonic):
        self.ask, self.ttl_s, self.now = ask, ttl_s, now
        self.seen: dict[int, float] = {}

    def __call__(self, pid: int) -> bool:
        t = self.now()
        if t - self.seen.get(pid, -math.inf) < self.ttl_s:
            return True
        if self.ask(pid):
            self.seen[pid] = t
            return True
        self.seen.pop(pid, None)
        return False


class ElasticClock(SegmentReading):
    """The clock interface of devices/clock.py (now, wall, sleep, asleep, iso, as_args) on a
    shared clock file, with ``claim`` / ``busy`` / ``idle_until`` for this process's slot; the
    segment read (and mended) as devices/clock_reading.py does."""

    def __init__(self, path: str | Path, wall_time: Callable[[], float] = time.time,
                 alive: Callable[[int], bool] | None = None, pause: Callable[[float], None] = time.sleep):
        """``wall_time``, ``alive`` (is that pid running; ``RecentlyAlive`` by default), ``pause`` (a
        blocking nap): injectable for tests. BadInput naming the file and the field if it is no sound
        clock file."""
        self.path = str(path)
        self._time, self._alive, self._pause = wall_time, alive or RecentlyAlive(), pause
        self._fd = os.open(self.path, os.O_RDWR)
        size = os.fstat(self._fd).st_size
        if size < SIZE:             # (mmap's own complaint names neither the file nor the fault)
            os.close(self._fd)
            raise BadInput(self.path, None, f"not a fishfarm clock file ({size} bytes, a clock file has {SIZE})")
        self._map = mmap.mmap(self._fd, SIZE)
        self._last = -math.inf
        self._seen: deque[tuple[float, float]] = deque(maxlen=SEEN_N)   # (wall, farm) read, SEEN_EVERY_S apart
        self._guard = threading.Lock()
        self._wlock = threading.Lock()          # this process's writer, held with the flock (below)
        self.slot: int | None = None
        self._said: tuple[int, float, str] | None = None
        self._renewed = -math.inf               # wall instant this process last gave its word
        self._redrawn = -math.inf               # ... last drew a stale segment again (clock_reading.py)
        self._good: Segment | None = None       # the last sound segment read, and when
        self._good_w = 0.0
        self._sound: tuple = ()                 # the raw segment last found sound
        self._stale: Segment | None = None      # read meanwhile: slow on from the last sound one
        self._lost: str | None = None           # why the file can no longer be read (cut short)
        self.on_lost: Callable[[], None] | None = None   # called once then (the process's stop)
        try:
            self.slow, self.fast, self.lease_s = check_file(self.path, self._map, self._time())
            self._renew_s = self.lease_s * RENEW_SHARE if self.lease_s > 0 else math.inf
            self._good, self._good_w = self._first_segment()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self._map.close()
        os.close(self._fd)

    def segment(self) -> Segment:
        return self._read()[0]

    def now(self) -> float:
        seg, w = self._read()
        t = seg.farm_at(w)
        with self._guard:
            self._last = t = max(t, self._last)
            if not self._seen or w - self._seen[-1][0] >= SEEN_EVERY_S:
                self._seen.append((w, t))
        return t

    def wall_since(self, farm_t: float) -> float:
        """Wall seconds since farm time ``farm_t`` was now (0 if it is yet to come): exact on the
        current segment; before its anchor, at least the wall since the first instant this process
        read a farm time past ``farm_t`` (its readings are kept ``SEEN_EVERY_S`` apart for a minute);
        before all of them, that much and the rest at the slow speed.
        ``wall`` cannot say it: a lag run up at the fast speed, read at the slow one (or a crawl),
        was ten thousand times too long -- contacts 20 ms late dropped as ones a stalled hub held."""
        seg, w = self._read()                 # (one read: it runs for every contact the hub sends)
        if farm_t >= max(seg.farm_at(w), self._last):
            return 0.0
        if farm_t >= seg.farm0:
            return max(0.0, w - seg.wall_at(farm_t))
        with self._guard:
            i = bisect.bisect_right(self._seen, farm_t, key=lambda s: s[1])
            if i == 0 and self._seen:         # before all this process read: at the slow speed, as the
                w0, f0 = self._seen[0]         # clock starts (and as the harness holds it while processes start)
                return max(0.0, w - w0) + (f0 - farm_t) / self.slow
            past = self._seen[i][0] if i < len(self._seen) else seg.wall0
        return max(0.0, w - min(past, seg.wall0))

    def at(self, wall: float) -> float:
        """Farm time at wall instant ``wall`` (a log record's, just made), on the current segment;
        an instant before the segment's anchor reads as the anchor (the earlier speed is gone), and
        no instant reads before the latest ``now()`` (held monotonic, as ``now`` is)."""
        seg = self.segment()
        # never before a time now() has given: a segment overwritten with an earlier anchor (a file
        # another program wrote) had log lines a day behind the ledger and the status
        return max(seg.farm_at(max(wall, seg.wall0)), self._last)

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
        if self._shrunk():
            return []
        return [decode_slot(SLOT.unpack_from(self._map, HEAD.size + i * SLOT.size)) for i in range(NSLOTS)]

    # -- declaring ----------------------------------------------------------------------------
    def claim(self, name: str, wait_s: float = CLAIM_WAIT_S) -> int:
        """This process's slot ``name`` (an awaited one, one a dead process held, or a free one).
        BadInput naming the file and the pid if a live process of another farm holds it (two farms
        on one file overwrote each other's word), after ``wait_s`` for it to end (a restarted
        controller's simulator starts while its predecessor's is still stopping)."""
        deadline = time.monotonic() + wait_s
        while (holder := self._claim(name)) is not None:
            if time.monotonic() >= deadline:
                raise BadInput(self.path, f"slot {name!r}", f"held by pid {holder}, which is running: one clock "
                                                            "file per farm (make another with fishfarm clock --out)")
            time.sleep(0.05)
        self._said, self._renewed = (BUSY, self.slow, "starting"), self._time()
        return self.slot

    def _claim(self, name: str) -> int | None:
        """Claim the slot; or the pid of the live process (not this one) that holds it."""
        with self._locked():
            if self._shrunk():
                raise BadInput(self.path, None, self._lost)
            slots = self.slots()
            mine = [i for i, s in enumerate(slots) if s.name == name and s.kind != EMPTY]
            held = [s.pid for s in slots if s.name == name and s.kind in (BUSY, IDLE)
                    and s.pid != os.getpid() and self._alive(s.pid)]
            if held:
                return held[0]
            free = [i for i, s in enumerate(slots) if s.kind == EMPTY]
            if not (mine or free):
                raise BadInput(self.path, "slots", f"all {NSLOTS} are taken by others: no slot for {name!r}")
            self.slot = (mine or free)[0]
            self._write_slot(name, BUSY, self.slow, "starting")
            self._govern()
        return None

    def busy(self, max_speed: float | None = None, why: str = "") -> None:
        """Farm time must run at no more than ``max_speed`` (default: the slow speed) from now."""
        speed = self.slow if max_speed is None or not max_speed > 0 else max_speed
        self._declare(BUSY, min(speed, self.fast), why)

    def idle_until(self, t: float, why: str = "") -> None:
        """Nothing here needs fine time before farm time ``t``."""
        # (a NaN or a time past the farm's last year would read as a spoilt slot)
        self._declare(IDLE, t if t < FARM_MAX else FARM_MAX - 1.0, why)

    def release(self) -> None:
        """This process leaves the farm's timeline (its slot is freed)."""
        if self.slot is not None:
            with self._locked():
                if not self._shrunk():
                    self._write_slot("", EMPTY, 0.0, "")
                    self._govern()
            self.slot, self._said = None, None

    def _declare(self, kind: int, value: float, why: str) -> None:
        if self.slot is None:
            raise RuntimeError("claim() a clock slot before declaring")
        if self._said == (kind, value, why) and self._time() - self._renewed < self._renew_s:
            return                              # unchanged, and its lease fresh: the segment already says so
        with self._locked():
            if self._shrunk():
                return                          # (the stop is under way: on_lost)
            self._write_slot(None, kind, value, why)
            self._govern()
        self._said, self._renewed = (kind, value, why), self._time()

    def govern(self) -> Segment:
        """Re-draw the segment from the slots now (the harness may call it; declaring does)."""
        with self._locked():
            return self._slow_on() if self._shrunk() else self._govern()

    def _shrunk(self) -> bool:
        """Whether the file is cut short (the map read past its end: a SIGBUS, no line said). Once
        seen: one line logged, ``on_lost`` called, farm time read on slow, nothing written."""
        if self._lost is not None:
            return True
        size = os.lseek(self._fd, 0, os.SEEK_END)
        if size >= SIZE:
            return False
        self._lost = f"the clock file shrank to {size} bytes (a clock file has {SIZE})"
        log.critical("%s: %s: farm time reads on at the slow speed; stopping", self.path, self._lost)
        if self.on_lost is not None:
            self.on_lost()
        return True

    def _govern(self) -> Segment:
        """Under the lock. The counter goes odd before the anchor's wall instant is read: a reader
        that got the old segment read its wall before that instant, where the old one holds."""
        old = self._mend()                     # (a dead writer's odd counter: re-drawn first)
        gen = struct.unpack_from("<Q", self._map, GEN_AT)[0]
        struct.pack_into("<Q", self._map, GEN_AT, gen + 1)
        try:
            w = self._time()
            f = max(old.farm_at(w), self._last)
            speed, limit, after = self._pace(f, w)
            if (old.speed, old.limit, old.after) == (speed, limit, after):
                return old
            new = Segment(w, f, speed, limit, after)
            SEG.pack_into(self._map, SEG_AT, new.wall0, new.farm0, new.speed, new.limit, new.after)
            return new
        finally:
            struct.pack_into("<Q", self._map, GEN_AT, gen + 2)

    def _pace(self, f: float, w: float) -> tuple[float, float, float]:
        """(speed, limit, after) the slots ask for at farm time ``f``, wall instant ``w``."""
        raws = [SLOT.unpack_from(self._map, HEAD.size + i * SLOT.size) for i in range(NSLOTS)]
        return pace_of(raws, f, w, self.slow, self.fast, self._alive, self.lease_s)

    def _write_slot(self, name: str | None, kind: int, value: float, why: str) -> None:
        at = HEAD.size + self.slot * SLOT.size
        if name is None:
            name = decode_slot(SLOT.unpack_from(self._map, at)).name
        live = kind != EMPTY
        SLOT.pack_into(self._map, at, utf8_16(name), os.getpid() if live else 0, kind, value, utf8_16(why),
                       self._time() if live else 0.0)

    def _locked(self):
        return Flock(self._fd, self._wlock)
