"""The demand filter's time (controller/demand.py): closing its 5 s bins as farm time passes, and
what a closed bin updates -- the window's sums, the persistence window, the background's and the
clustering's shares of empty spans, the sensors' fault tests, the slow-fish note."""
from __future__ import annotations

import math

from controller.demand_stats import LONG_BUSY_BINS
from controller.demand_types import SensorFault, SensorRecovered, SlowFishUndetectable
from controller.demand_window import TankWindow


class Bins:
    """Mixin of DemandFilter: ``params``, ``_bin``, ``_alpha``, ``_alpha_c``, ``_faults`` and the
    methods ``_thresholds``, ``slow_fish``, ``_drained``, ``_push_persist``, ``_max3``, ``_clump``
    are its."""

    def _roll(self, ts: TankWindow, t: float):
        """Close the current bin and any empty ones up to the bin holding ``t``."""
        if ts.bin_end == -math.inf:
            ts.bin_end = (math.floor(t / self._bin) + 1) * self._bin
            return None
        steps = int((t - ts.bin_end) // self._bin) + 1
        n = len(ts.vals)
        t_judged = ts.bin_end + (steps - 1) * self._bin          # stuck and dead sensor tests
        if ts.cur and not ts.excl:                  # a bin with healthy contacts: shares of the sensors
            ts.active_ew = ts.active_ew * self._faults.decay ** steps + 1.0
        else:
            ts.active_ew *= self._faults.decay ** steps
        # the bin is evidence against a silent sensor only if one that fired is not long busy: fish on
        # one sensor for minutes (or one stuck) made its healthy neighbour "dead" (an outside tester)
        spread = any(s.n and s.busy < LONG_BUSY_BINS for s in ts.sensors.values())
        judged = self._faults.judge(ts.sensors, ts.active, ts.active_ew, bool(ts.cur and not ts.excl),
                                    t_judged, steps)
        events = [SensorRecovered(ts.name, s, t_judged) if kind is None else SensorFault(ts.name, s, t_judged, kind)
                  for s, kind in judged] if judged else None
        if ts.raw > self._beat_bin or (ts.excl and ts.raw):   # a bin too busy for a beat
            ts.beats.forget(ts.bin_end - self._bin, ts.bin_end)
        for k in range(min(steps, n + 1)):
            self._close_bin(ts, spread and k == 0)     # the bins after the first are empty
        for _ in range(min(steps, len(ts.lvals) + 1) - min(steps, n + 1)):
            self._push_persist(ts, 0)               # a silence longer than the window
        ts.m_old = self._max3(ts) if ts.vsum else 0
        if steps > n + 1:                           # a long silence: every span was empty
            a = self._alpha ** (steps - (n + 1))
            ts.bg_n = ts.bg_n * a + (1 - a) / (1 - self._alpha)
            ts.bg_t = ts.bg_t * a + (1 - a) / (1 - self._alpha)
            a = self._alpha_c ** (steps - (n + 1))
            ts.cl_n = ts.cl_n * a + (1 - a) / (1 - self._alpha_c)
            ts.cl_t = ts.cl_t * a + (1 - a) / (1 - self._alpha_c)
            ts.cl_one *= a
        ts.bin_end += steps * self._bin
        self._thresholds(ts)
        if not ts.told and ts.bg_t * self._bin >= self.params.learn_s + 900.0:
            note = self.slow_fish(ts.name)
            if note is not None:
                ts.told = True
                events = [*(events or ()), SlowFishUndetectable(ts.name, ts.bin_end, note)]
        beats, old = ts.beats, ts.bin_end - self._bin - ts.beats.window
        if (beats.times and beats.times[0] < old) or beats.gaps:
            beats.trim(old)
        if ts.demanding and ts.osum + ts.occ < self.params.end_fraction * ts.k:
            self._drained(ts)
        return events

    def _close_bin(self, ts: TankWindow, spread: bool = False) -> None:
        """``spread``: its contacts are not all of sensors busy in every bin for minutes (_roll)."""
        v = 0 if ts.excl else ts.cur
        r = 0 if ts.excl else ts.raw
        h = ts.head
        ts.vsum += v - ts.vals[h]
        ts.rsum += r - ts.raws[h]
        ts.vals[h], ts.raws[h] = v, r
        ts.osum += ts.occ - ts.occs[h]
        ts.occs[h] = ts.occ
        ts.head = (h + 1) % len(ts.vals)
        self._push_persist(ts, v)
        ts.p2, ts.p1 = ts.p1, v
        if v:
            self._clump(ts, h)
        if not ts.demanding:                        # background: is the span of the window empty? one?
            ts.bg_n = ts.bg_n * self._alpha + (ts.vsum == 0)
            ts.bg_t = ts.bg_t * self._alpha + 1.0
            ts.cl_n = ts.cl_n * self._alpha_c + (ts.vsum == 0)
            ts.cl_one = ts.cl_one * self._alpha_c + (ts.vsum == 1)
            ts.cl_t = ts.cl_t * self._alpha_c + 1.0
            ts.bg_seen += 1
        if ts.vals[h] and spread:                   # a non-chatter bin with healthy contacts
            ts.active += 1
        ts.cur = ts.raw = ts.occ = 0
        ts.excl = False
        ts.tail, ts.excl_next = ts.excl_next, False     # the next bin, until the run pauses
        ts.run_prev, ts.run_cur = ts.run_cur, 0
