"""A tank's evidence window and the burst rules that cut it (controller/demand.py explains them).

``BurstRules`` is mixed into ``DemandFilter``: it uses the filter's ``params``, ``_bin`` (bin
length, s) and ``_no_fish`` (a bin's contacts no fish ever make)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

from controller.demand_stats import Beats, Sensor

if TYPE_CHECKING:
    from controller.demand_types import DemandParams

__all__ = ["BurstRules", "Persistence", "TankWindow"]

PERSIST_RECENT = 0.35   # the persistence count's recent half alone holds this share of its threshold:
                        # fish still there, not the tail of an episode that ended minutes ago


class TankWindow:
    """A tank's evidence: the current bin, the window's ring of complete bins, the run of
    contacts going on, its background estimate and demand state."""

    __slots__ = ("name", "sensors", "bin_end", "slot", "cur", "raw", "excl", "excl_next", "vals",
                 "raws", "head", "vsum", "rsum", "m_old", "p1", "p2", "k", "bg_n", "bg_t", "cl_n", "cl_one", "cl_t",
                 "demanding", "last_raise", "fresh", "recent", "active", "last_t", "prev_c", "tail",
                 "run_cur", "run_prev", "run_len", "run_t0", "cap", "run_n", "run_cnt",
                 "occ", "occs", "osum", "beats", "grid_i", "told", "active_ew", "bg_seen",
                 "lvals", "lhead", "lsum", "hsum", "kp")

    def __init__(self, name: str, n_bins: int, k: int, bg_n: float, bg_t: float, beats: Beats,
                 persist_bins: int = 0):
        self.name = name
        self.sensors: dict[str, Sensor] = {}
        self.bin_end = -math.inf
        self.slot = -math.inf                      # no second counted yet (t may be negative)
        self.cur = self.raw = 0                     # current bin: occupied slots, contacts
        self.excl = self.excl_next = False
        self.vals = [0] * (n_bins - 1)              # complete bins in the window (ring)
        self.raws = [0] * (n_bins - 1)
        self.head = 0
        self.vsum = self.rsum = self.m_old = self.p1 = self.p2 = 0
        self.k, self.bg_n, self.bg_t = k, bg_n, bg_t
        self.cl_n = self.cl_one = self.cl_t = 0.0   # spans empty, of one busy second, all: over a longer time
        self.bg_seen = 0                            # background bins measured (the prior's not among them)
        self.cap = 1 << 30                          # busy seconds a run may count in its first BURST_S
        self.demanding, self.last_raise, self.fresh = False, -math.inf, 0
        self.recent: list[float] = []
        self.active = 0                             # bins with a healthy contact (dead-sensor test)
        self.last_t = -math.inf                     # the previous contact in a new second
        self.prev_c = -math.inf                     # the previous contact
        self.tail = False                           # a burst's tail: its contacts count nothing
        self.run_cur = self.run_prev = 0            # busy seconds of the current run, this bin and the last
        self.run_len = 0                            # busy seconds of the current run
        self.run_t0 = -math.inf                     # its first contact
        self.run_n = self.run_cnt = 0               # its contacts; its busy seconds counted
        self.occ = self.osum = 0                    # busy seconds, excluded bins included
        self.occs = [0] * (n_bins - 1)
        self.beats, self.grid_i = beats, -1
        self.told = False                           # slow fish said undetectable
        self.active_ew = 0.0                        # the same, decaying (shares of sensors)
        self.lvals = [0] * max(2, persist_bins - 1)  # the persistence window's complete bins (ring)
        self.lhead = 0
        self.lsum = self.hsum = 0                   # its busy seconds, and its recent half's
        self.kp = 1 << 30                           # its threshold (off: never reached)


class BurstRules:
    """Chatter, clumps, bursts that raised a demand, and pairs: edits of a ``TankWindow``."""

    params: DemandParams
    _bin: float
    _no_fish: int

    def _chatter_bin(self, ts: TankWindow) -> None:
        """This bin is too fast for fish: it counts for nothing. At twice the fastest fish (no
        fish, ever) its neighbours go too: they hold the burst's ramp and tail."""
        if not ts.excl:
            ts.excl = True
            ts.cur = 0
            if ts.last_raise >= ts.run_t0:          # the burst raised the last demand
                self._retract(ts)
        if ts.raw == self._no_fish and not ts.excl_next:
            ts.excl_next = True
            last = (ts.head - 1) % len(ts.vals)
            cut = min(ts.run_prev, ts.vals[last])    # the burst's own seconds in the bin before
            ts.vsum -= cut
            ts.vals[last] -= cut
            ts.p1 = ts.vals[last]
            ts.m_old = self._max3(ts)
            ts.beats.forget(ts.bin_end - 2 * self._bin, ts.bin_end)

    def _clump(self, ts: TankWindow, h: int) -> None:
        """A quiet tank (the other 50 s of the window hold few busy seconds), then 10 s with >=
        clump_contacts contacts at >= 2 per busy second: a short burst too slow for the chatter
        test (fish below 1.5 /s give < 2 per busy second, bursts at >= 3 /s give >= 3.2)."""
        prev = h - 1 if h else len(ts.vals) - 1
        raw = ts.raws[h] + ts.raws[prev]
        if (raw >= self.params.clump_contacts and 2 * raw >= 5 * (ts.occs[h] + ts.occs[prev])
                and 2 * (ts.osum - ts.occs[h] - ts.occs[prev]) <= len(ts.vals)):
            ts.vsum -= ts.vals[h] + ts.vals[prev]
            ts.rsum -= raw
            ts.vals[h] = ts.vals[prev] = ts.raws[h] = ts.raws[prev] = ts.p1 = ts.p2 = 0
            ts.excl_next = True                     # and the bin that follows
            ts.beats.forget(ts.bin_end - 2 * self._bin, ts.bin_end)
            if ts.last_raise >= ts.bin_end - 2 * self._bin:
                self._retract(ts)

    def _pair(self, ts: TankWindow) -> None:
        """The run that just ended held two contacts, the second not counted: count it in the
        bin of the first, if that bin still counts and is still in the window."""
        start = ts.bin_end - self._bin              # the current bin's
        if ts.run_t0 >= start:
            if ts.cur and not ts.excl:
                ts.cur += 1
            return
        back, n = int((start - ts.run_t0) // self._bin) + 1, len(ts.vals)
        i = (ts.head - back) % n
        if back > n or not ts.vals[i]:              # gone, or cut as a burst's
            return
        ts.vals[i] += 1
        ts.vsum += 1
        if back == 1:
            ts.p1 += 1
        elif back == 2:
            ts.p2 += 1
        ts.m_old = self._max3(ts)

    @staticmethod
    def _retract(ts: TankWindow) -> None:
        """The last demand was raised by what has since proved a burst: it holds nothing back
        (no repeat wait, not in demand), and the next demand needs evidence from after the burst:
        the window's busy seconds so far are dropped."""
        ts.last_raise, ts.demanding = -math.inf, False
        for i in range(len(ts.vals)):
            ts.vals[i] = 0
        ts.vsum = ts.p1 = ts.p2 = ts.m_old = 0

    def _max3(self, ts: TankWindow) -> int:
        vals, h, n = ts.vals, ts.head, len(ts.vals)
        seq = vals[h:] + vals[:h]
        return max(seq[i] + seq[i + 1] + seq[i + 2] for i in range(n - 2))


class Persistence:
    """The persistence count (a mixin of ``DemandFilter``, which gives ``params``, ``_persist``
    (its window, s) and ``_start``): the busy seconds the count takes, summed over a window of
    minutes against a threshold of their own from the same Poisson tail (``kp``, a small budget),
    for slow fish the minute's count misses (at 0.1 /s on a tank at 0.04 /s of turbulence, 14 of 20
    ten-minute episodes were raised before; 19 with it). Its ring restarts when a demand drains, so
    an episode raised already is not raised again by its tail and a little turbulence."""

    def _persisting(self, ts: TankWindow, t: float, events):
        """The persistence count: slow fish the minute's count missed, raised once they have kept
        at it (at most once a persistence window), while its recent half still holds them and the
        last minute holds what would keep a demand going (``end_fraction`` x k), on a
        contact within one pace of the one before (the window outlasts the fish: a turbulence
        contact long after them must not be the one that raises)."""
        total = ts.lsum + ts.cur
        pace = self._persist / total
        if (t - ts.last_raise < self._persist or t - ts.last_t > pace
                or ts.raw > 3 * ts.occ + 1 or ts.hsum + ts.cur < PERSIST_RECENT * ts.kp
                or ts.vsum + ts.cur < self.params.end_fraction * ts.k):     # the last minute too
            return events
        return self._start(ts, t, events)

    @staticmethod
    def _drained(ts: TankWindow) -> None:
        """A demand's evidence has drained: the persistence count starts afresh (what it held was
        that episode's, raised already; its tail and a little turbulence raised it again minutes
        after the fish had stopped)."""
        ts.demanding = False
        ts.lvals[:] = [0] * len(ts.lvals)
        ts.lsum = ts.hsum = 0

    @staticmethod
    def _push_persist(ts: TankWindow, v: int) -> None:
        """A complete bin into the persistence window's ring, and its recent half's sum."""
        lv, h = ts.lvals, ts.lhead
        n = len(lv)
        ts.lsum += v - lv[h]
        lv[h] = v
        ts.hsum += v - lv[(h - n // 2) % n]
        ts.lhead = (h + 1) % n
