"""How an elastic clock (devices/elastic_clock.py) reads its file's segment: never locking, never
looping without end, mending what a writer that died mid-write left, and drawing again a segment
every holder has left (a mixin of ``ElasticClock``: its map, descriptor, wall, speeds, lease and
``_govern``/``_pace``/``_shrunk``)."""
from __future__ import annotations

import fcntl
import logging
import math
import os
import struct
import time

from devices.clock_file import GEN_AT, SEG, SEG_AT, SIZE, Segment, segment_fault
from devices.errors import BadInput

WRITER_WAIT_S = 0.1                          # wall: how long a reader waits for a live writer mid-write
                                             # before it reads slow on (once per write: a stopped writer
                                             # is not waited for at every read)
STALE_S = 1.0                                # wall: a segment nobody drew again for this long while words are
                                             # leases (given every few ms) is every holder's stopped or dead:
                                             # a reader draws it again (a dead holder's word is slow, not the
                                             # crawl the last lapsed word left; not a farm's for good)
SPINS = 200                                  # reads of an odd counter before looking for its writer (a
                                             # write takes microseconds; 200 reads are ~50 us)
log = logging.getLogger("fishfarm.clock")


class SegmentReading:
    def _read(self) -> tuple[Segment, float]:
        """The segment and a wall instant it holds at: the wall is read inside the sequence check,
        so a segment re-drawn after that instant (anchored later) cannot be mixed with it.

        Never loops without end: a counter still odd after SPINS reads, or a segment that is no
        sound one, is a writer's that died mid-write (SIGKILL between the counter's two steps) if
        nobody holds the file's lock -- then it is re-drawn from the slots -- or one a live writer
        is in the middle of; meanwhile the farm runs on at the slow speed from the last sound
        segment read (slow is always safe)."""
        if self._lost is None and os.lseek(self._fd, 0, os.SEEK_END) >= SIZE:   # (_shrunk's check, inline)
            read = self._try_read() or self._settle(0.0 if self._stale is not None else WRITER_WAIT_S)
            if read is not None:
                if self.lease_s > 0 and read[1] - read[0].wall0 > STALE_S and read[1] - self._redrawn > STALE_S:
                    self._redrawn = read[1]
                    read = self._mend_if_free(redraw=True) or read
                (self._good, self._good_w), self._stale = read, None
                return read
        else:
            self._shrunk()
        return self._slow_on(), self._time()

    def _settle(self, wait_s: float) -> tuple[Segment, float] | None:
        """(segment, wall) read soundly, or mended if its writer is dead; None if a live writer
        holds the file mid-write for longer than ``wait_s`` (descheduled on a loaded machine: a
        few ms; stopped: for good)."""
        deadline = None
        while True:
            if (read := self._try_read()) is not None:
                return read
            if (mended := self._mend_if_free()) is not None:
                return mended
            now = time.monotonic()
            deadline = now + wait_s if deadline is None else deadline
            if now >= deadline:
                return None
            time.sleep(0.0001)                 # (lets a writer thread of this process have the GIL)

    def _try_read(self) -> tuple[Segment, float] | None:
        for _ in range(SPINS):
            g1 = struct.unpack_from("<Q", self._map, GEN_AT)[0]
            if g1 & 1:
                continue                       # a writer is in the middle: its write takes microseconds
            raw = SEG.unpack_from(self._map, SEG_AT)
            w = self._time()
            if struct.unpack_from("<Q", self._map, GEN_AT)[0] == g1:
                seg = Segment(*raw)
                if raw != self._sound:         # checked once per segment (its anchor stays in the past)
                    if segment_fault(seg, w, self.fast) is not None:
                        return None
                    self._sound = raw
                return seg, w
        return None

    def _first_segment(self, wait_s: float = 1.0) -> tuple[Segment, float]:
        """The segment at opening: read, or mended, or -- a writer holding the file mid-write for
        ``wait_s`` (stopped: ^Z) -- the file's segment as it is if sound. BadInput if none is."""
        if (read := self._settle(wait_s)) is not None:
            return read
        seg, w = Segment(*SEG.unpack_from(self._map, SEG_AT)), self._time()
        if (fault := segment_fault(seg, w, self.fast)) is not None:
            raise BadInput(self.path, "segment", fault)
        return seg, w

    def _slow_on(self) -> Segment:
        """The farm time read while the file's segment cannot be: on at the slow speed (or slower,
        if that segment was) from the last sound segment's last reading -- not extrapolated on that
        segment's speed, which the writers may have lowered since."""
        if self._stale is None:
            f = self._good.farm_at(self._good_w)
            s = min(self.slow, self._good.speed_at(f))
            self._stale = Segment(self._good_w, f, s, math.inf, s)
        return self._stale

    def _mend_if_free(self, redraw: bool = False) -> tuple[Segment, float] | None:
        """Mend the segment (``redraw``: draw it again from the slots) if no writer holds the file
        (here or elsewhere): (it, a wall instant read under the lock, where no later segment can be
        anchored); None if a writer holds it."""
        if not self._wlock.acquire(blocking=False):
            return None                        # this process is writing (another thread, a signal handler)
        try:
            try:
                fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return None                    # a live writer in the middle of its write
            try:
                if self._shrunk():
                    return None
                return (self._govern() if redraw else self._mend()), self._time()
            finally:
                fcntl.flock(self._fd, fcntl.LOCK_UN)
        finally:
            self._wlock.release()

    def _mend(self) -> Segment:
        """Under the lock: the segment, re-drawn from the slots if the counter is odd (its writer
        died mid-write: nobody else can hold the lock) or the segment is no sound one. BadInput if
        neither the file's segment nor one read before is sound."""
        gen = struct.unpack_from("<Q", self._map, GEN_AT)[0]
        seg, w = Segment(*SEG.unpack_from(self._map, SEG_AT)), self._time()
        fault = segment_fault(seg, w, self.fast)
        if not gen & 1 and fault is None:
            return seg
        base = seg if fault is None else self._good
        if base is None:
            raise BadInput(self.path, "segment", fault)
        odd = gen if gen & 1 else gen + 1
        struct.pack_into("<Q", self._map, GEN_AT, odd)
        try:
            f = max(base.farm_at(w), self._last)
            new = Segment(w, f, *self._pace(f, w))
            SEG.pack_into(self._map, SEG_AT, new.wall0, new.farm0, new.speed, new.limit, new.after)
        finally:
            struct.pack_into("<Q", self._map, GEN_AT, odd + 1)
        log.warning("%s: %s; re-drawn from the slots at %.6g x", self.path,
                    "a writer died mid-write" if gen & 1 else f"segment {fault}", new.speed_at(f))
        return new
