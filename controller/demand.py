"""Demand filter: tells hungry fish from turbulence and broken sensors, tank by tank.

Pure, clock-free and incremental: ``on_contact(t, tank, sensor)`` for each rising edge (time
order), ``on_time(t)`` every few farm seconds; both return events (``Demand``, ``SensorFault``,
``SensorRecovered``, ``SlowFishUndetectable``). The controller and ``fishfarm demand`` (offline CSV
replay) run this code.

The model (DESIGN.md) and what follows from it
----------------------------------------------
fish demand 0.1–2 /s for 1–10 min; turbulence Poisson below 0.05 /s plus chatter bursts of
3–20 /s lasting < 10 s; stuck sensors (a fixed high rate for minutes) and dead ones (silent while
the tank's other sensors fire). A demand must come within 60 s of an episode's start, never
outside one. The operating point (issue 6): a false demand costs one portion (never past the
ration), a missed one leaves fish hungry for hours; so recall within 60 s of an episode's first
contact comes first, at <= 0.5 false demands per tank-day.

*Slow fish: what any filter can do.* 60 s after the first contact of a Poisson episode at r /s
hold 1 + Poisson(60 r) fish contacts (7 on average at 0.1 /s), plus Poisson(60 b) of turbulence.
The best test of a Poisson rate change over a fixed window is the count; under turbulence alone
a sliding count reaches k at the rate b·P[Poisson(60 b) = k-1] a second, so 0.5 false demands a
day fixes k(b). The ideal recall, P[1 + Poisson(60 (r + b)) >= k] (``caught_within``; the
measured bound ``tests/contract_streams.oracle_recall`` agrees), and the slowest rate caught at
0.99 (``rate_for``):

    b /s    k   r = 0.1  0.15  0.2   0.25  0.3   0.99 from
    0.002   4       0.94  0.99  1.00  1.00  1.00  0.14 /s
    0.005   5       0.87  0.98  1.00  1.00  1.00  0.17 /s
    0.01    6       0.79  0.96  1.00  1.00  1.00  0.19 /s
    0.02    8       0.58  0.88  0.98  1.00  1.00  0.24 /s
    0.05   13       0.20  0.54  0.82  0.95  0.99  0.36 /s

So Poisson fish at exactly 0.1 /s are not caught at 0.99 within 60 s on any real tank: 0.94 on a
nearly silent one, 0.58 at 0.02 /s. Recall 0.99 across the band holds from ~0.25 /s at 0.02 /s.
Where a tank's measured turbulence makes its slowest fish (``slow_fish_hz``) more likely missed
than served (ideal recall < ``slow_fish_recall``), after ``learn_s`` of measuring, the filter
says so once per tank (``SlowFishUndetectable``; ``slow_fish(tank)`` for status) rather than
missing them silently; such episodes are raised later if they persist. Measured on the
independent streams, per named case: README, ``bench/bench_demand.py``.

*The statistic.* Time is cut into 5 s bins; a bin's value is the number of distinct 1 s slots
holding a contact (0–5). Evidence is the sum over the last 60 s (12 bins), the whole time the
deadline allows. Counting occupied seconds rather than contacts caps any short clump (a chatter
burst of 200 contacts in 8 s counts at most 9), while losing little for fish (rate r fills
1 - e^-r of the seconds: 95 % of the information at 0.1 /s, still ~0.86 /s at 2 /s).

*Runs.* Bursts are collapsed to one event: a run is contacts each < ``RUN_GAP_S`` (1 s) after
the one before; for its first ``BURST_S`` (10 s, the contract's longest burst) a run counts at
most max(``run_cap`` (1), k / 4) busy seconds, after that every busy second again (fish pacing
at 2 /s form one long run; a burst never lasts 10 s; on a turbulent tank, k >= 8, fast Poisson
fish need their runs' seconds, and a burst is a smaller share of k). Slow fish lose little (at 0.15 /s a contact follows
the one before within 1 s 14 % of the time), a 3–20 /s burst counts ~1–2 whatever its size,
so a burst plus a minute's turbulence rarely reaches the threshold: the false demands this
saves pay for the lower threshold below (``false_alarms_per_day`` 1.5, was 1). A run of exactly
two contacts counts two, once it has ended (at the next contact): a burst almost always holds
more, while two contacts of slow fish fall within 1 s of each other at the rate's own odds
(~10 % of contacts at 0.1 /s), and counting the pair as one cost them a contact at the margin.

*Chatter.* A bin with >= chatter_hz x 5 = 15 contacts counts 0 (2 /s fish reach that in ~9 % of
bins, a 3 /s stuck switch in all); at >= 20 (4 /s, never fish) the burst's own busy seconds in the
bin before go too (those since its run began: contacts < ``RUN_GAP_S`` apart), and in the bin
after, its contacts until the run pauses. On a quiet tank, 10 s holding >= ``clump_contacts``
contacts at >= 2.5 per busy second is a short burst and counts 0. Bursts at the slow end of
their band (3 /s Poisson) cannot be told from 2 /s fish locally: only duration separates them
(< 10 s against >= 1 min). Hence *persistence*: the
densest 15 s of the window may add no more than ``spike_gain`` (3) x what the other 45 s hold per
15 s, plus ``spike_allowance`` (2); steady fish count in full, a burst on a quiet tank adds
little (runs already collapse most bursts; the old 2 and 1 cost slow fish at an episode's
start, whose contacts crowd the window's end).

*The threshold.* Under turbulence alone, contacts at rate b upcross a sliding count k over a
window W at the rate b·P[Poisson(bW) = k-1] per second (a Poisson arrival sees the window's
stationary count; capping and the exclusions above only lower it). k is the least integer with
86,400 × that ≤ ``false_alarms_per_day`` (default 1.5: nominal; busy seconds, runs, the burst
rules and the margin below bring the measured rate to 0.1–0.4 a tank-day). At 0.05 /s, k = 12 busy
seconds in 60 s; at 0.01 /s, 6; never below ``min_contacts``. b is the tank's own, learned from
what it measures: the share of empty 55-s spans (the window's complete bins) outside demand,
exponentially weighted over ``background_tau_s``, is e^(-55 b) under Poisson turbulence, and its
lower confidence bound (one s.d.) gives b with a margin. Unlike a mean count, the share of empty
spans hardly moves when undetected slow episodes (contacts for minutes) or bursts pass. It is
clipped to [floor, 4 × max] and starts at ``turbulence_max_hz``, so a fresh filter is
conservative (an hour of measuring brings it to the tank's own); for the first ``PRIOR_S`` of
measuring it is at most that (the prior's own lower bound was the grid's top: a fresh filter, after
every restart, missed episodes below ~0.5 /s; 2026-12-04).

*Clusters.* Sparse random contacts may come as a wave's few hits on one sensor, 1–5 s apart: the
empty spans then count the hits, not the contacts, and the Poisson threshold at the hits' rate
let 1–3 hits at 0.015 /s (0.03 contacts/s) raise 72 false demands a day (2 hits at 0.02 /s: 97).
Under clusters at rate c, a share q of one busy second, a span holds none with probability e^-λ
and exactly one with λq·e^-λ (λ = c × span), so q comes from the shares of empty and single spans
(exponentially weighted as the empty share; its upper bound at two s.d., a calm tank's few
non-empty spans read ~1 ± 0.3 otherwise); like the empty share it hardly moves when undetected
slow fish pass, whose spans hold several. On ``SINGLE_LEVELS`` below 1, the count's thresholds are
the compound-Poisson tail of clusters of 1 (q), else 2 or 3 busy seconds (``clustered_threshold``:
Panjer's recursion; longer clumps are the burst and persistence rules'), and the beat's λ is scaled
by the mean cluster size (a wave's evenly spaced hits are cycles of a beat for free). Measured:
README, "Clustered turbulence". Poisson tanks (q read ~1) keep the thresholds below.

*The beat.* Fish bumping at a steady pace are far from Poisson, which the count ignores. m
cycles of a lattice of period P in ``beat_period_s`` (2–12 s), one contact each within ±δP of
its point (δ = 0.15 and 0.35: tight and loose beats; turbulence in between ignored), ending at
the latest contact, have surprise S = m·(-log 2δPb) under turbulence b. A union bound over all
lattices (controller/demand_stats.py: the search, the bound and its simulation) gives λ for
``beat_false_alarms_per_day`` (0.05, half per δ) over the b·86,400 contacts of a day: ~18 at
b = 0.05, ~14 at 0.01. Only single contacts count (a fish bump is one contact; two within
``beat_single_s`` are a burst's), outside bins of > 4; a cycle whose window a dropped burst
covered may pass empty. Raised on the contact that ends the beat, never repeated by it. A beat
at 0.1 /s has 6 cycles in 60 s: S = 6 × 3.5 = 21 clears λ at b = 0.01, not at 0.02 (6 × 2.8).

*What that buys.* Measured on the independent contract streams (tests/contract_streams.py,
``bench/bench_demand.py``; recall within 60 s of an episode's first contact, background 0.002–
0.02 /s, bursts 3 /h, 432 episodes a case; ``bound``: the ideal detector above on the same
stream): see the README's tables. In short: every episode of fish peaking at 0.4–2 /s within
60 s (`every`: 432 of 432 on the bench's seed, 864 of 864 on held-out seeds 21–22); ~0.99 from
0.2–0.3 /s; 0.68 at 0.1 /s (bound 0.75; 0.53 before runs, 0.64 before pairs); false demands
0.25–0.34 per tank-day over the cases, 0.14–0.22 over tank-days of background, bursts and waves
alone.

*Episodes and repeats.* One demand when the score first reaches k, raised on the contact that
made it, and only if that contact followed the previous one within three times the episode's own
pace (window / score; twice cost slow fish, whose gaps are exponential, a raise in ~1 of 6) and
is not in a clump (> 3 contacts per busy second): after fish stop, the next contact is
turbulence tens of seconds later, or a burst, and must not be the one that raises.
The tank is "in demand" until its busy seconds (exclusions ignored) fall below ``end_fraction``
x k. While in demand a demand is repeated at most every ``repeat_s``, on fresh evidence only:
``repeat_contacts`` busy seconds after the repeat fell due, each gap <= 3 x pace, the last <= 1 x
pace, spanning >= half their share of the window (a burst's seconds come faster). Only counted
busy seconds (not chatter, a burst's tail or a run past its cap) raise or repeat. *A burst's
demand holds nothing back*: when the run that raised the last demand proves a burst (its bin
turns chatter, or a clump is cut), the tank leaves demand and the repeat wait is cleared, so
fish that follow the burst are raised on their own evidence (before, the 120 s repeat rule
held such an episode back). Residual
risk: a turbulence contact right after an episode's end can still be the raising one: the
independent streams count those within 10 s of an end apart (``afterglow``).

*Persistence.* Slow fish the minute's count misses are raised once they have kept at it: the
same busy seconds over ``persist_window_s`` (controller/demand_window.py, ``Persistence``).

*Faults.* Stuck: a sensor's own count is ≥ 0.9 × stuck_rate_hz × 5 in ≥ ``stuck_share`` of its
5 s bins over ``stuck_window_s`` (fish at 2 /s exceed that in 21 % of bins, a 3 /s stuck sensor in
~all; chatter lasts < 10 s). It is left out until it has had no fast bin for ``recover_s``. Also
stuck, whatever its rate: firing in every 5 s bin for 15 min, past the contract's longest episode
(``EPISODE_MAX_S``; one at a fixed 1-2.5 /s for an hour was fed every 2 min); back once silent for
``recover_s``. A bin is evidence against a silent sensor only if a sensor that fired in it has not
fired in every bin for 2 min (``LONG_BUSY_BINS``): fish crowding one sensor made the other "dead".
Dead: silent for ``dead_after_s`` and ``dead_active_bins`` of the tank's active bins (bins with
healthy, non-chatter contacts) since its last contact, and so many that a live sensor would
almost never miss them all: (1 - q)^N < ``dead_p`` (1e-6 per bin: ~1e-3 false faults a
tank-day), q its learned share of the tank's active bins (decaying over 6 h, with 10 min of
equal shares as prior, so a never-heard sensor is judged too). A sensor in a quiet corner
(q = 0.1) needs ~130 active bins, one sharing half the tank's contacts 20. Its next contact is
a recovery. A tank with one sensor cannot tell a dead sensor from calm fish and never reports one.

Performance: on_contact does O(1) work with no allocation on the common path (a contact in an
already occupied second, or a tank far below threshold returns a shared empty tuple); the beat
search runs only on single contacts of a tank with enough of them, capped at
``beat_search_nodes``.
"""
from __future__ import annotations

import math

from controller.demand_bins import Bins
from controller.demand_stats import (
    HEALTHY,
    STUCK,
    Beats,
    Sensor,
    SensorTests,
    beat_tests,
    threshold,
)
from controller.demand_thresholds import CLUSTER_TAU_FACTOR, PRIOR_S, Thresholds
from controller.demand_types import Demand, DemandParams, SensorFault, SensorRecovered, SlowFishUndetectable
from controller.demand_window import BurstRules, Persistence, TankWindow

__all__ = ["Demand", "DemandFilter", "DemandParams", "SensorFault", "SensorRecovered", "SlowFishUndetectable",
           "threshold"]
_NONE: tuple = ()
FISH_MAX_HZ = 2.0       # the contract's fastest fish
RUN_GAP_S = 1.0         # contacts closer than this continue a run (a burst's tail goes with it)
BURST_S = 10.0          # the contract's longest chatter burst: a run lasting longer is not one
RAISE_GAP_PACES = 3.0   # the raising contact follows the one before within this many paces
PRIOR_BEAT_WINDOW_S = 180.0   # the beat looks back this far on a tank still at its prior: a steady 10 s pace
                              # from a fresh filter's first contact was never raised over 60 s (the count at
                              # 0.05 /s cannot see it); 180 s for every tank made the bench's farm stream
                              # replay 1.65x slower (a search on nearly every contact at 0.05 /s)
SUSPECT_BINS = 0b111    # a sensor stuck-fast this many bins in a row (15 s, past any burst) counts nothing


class DemandFilter(Bins, BurstRules, Persistence, Thresholds):
    """See the module docstring. ``tanks``: tank -> its sensors; None: learn them from contacts."""

    def __init__(self, params: DemandParams | None = None, tanks: dict[str, list[str]] | None = None):
        p = self.params = params or DemandParams()
        self._bin, self._inv_slot = p.bin_s, 1.0 / p.slot_s
        self._n = max(6, round(p.window_s / p.bin_s))
        self._chatter = max(2, math.ceil(p.chatter_hz * p.bin_s))
        self._no_fish = max(self._chatter + 1, math.ceil(2 * FISH_MAX_HZ * p.bin_s))  # twice what fish do
        self._faults = SensorTests(p)
        self._alpha = math.exp(-p.bin_s / p.background_tau_s)
        self._alpha_c = math.exp(-p.bin_s / (CLUSTER_TAU_FACTOR * p.background_tau_s))
        hi = 4.0 * p.turbulence_max_hz
        self._b_grid = [p.turbulence_floor_hz * (hi / p.turbulence_floor_hz) ** (i / 63) for i in range(64)]
        self._window = self._n * p.bin_s
        self._span = (self._n - 1) * p.bin_s            # the complete bins of a window
        self._k_grid = [threshold(b, self._window, p.false_alarms_per_day, p.min_contacts) for b in self._b_grid]
        self._k_at: dict[tuple[int, int], tuple[int, int]] = {}   # (b, clustering) -> (k, kp), as needed
        self._beat_at: dict[tuple[int, int], tuple] = {}         # (b, clustering) -> the beat's tests
        # (window, grid) of the beat test: over beat_window_s once the tank's turbulence is measured,
        # and over PRIOR_BEAT_WINDOW_S while it is the prior (its count at the contract's bound)
        self._beats = [(w, [beat_tests(b, p.beat_jitter, p.beat_false_alarms_per_day, p.beat_period_s, w)
                            for b in self._b_grid])
                       for w in (p.beat_window_s, max(p.beat_window_s, PRIOR_BEAT_WINDOW_S))]
        self._persist = p.persist_window_s
        self._persist_bins = round(self._persist / p.bin_s) if self._persist else 0
        self._kp_grid = [threshold(b, self._persist, p.persist_false_alarms_per_day,
                                   max(p.min_contacts, math.ceil(b * self._persist) + 1)) if self._persist else 1 << 30
                         for b in self._b_grid]
        self._beat_bin = math.ceil(p.bin_s / p.beat_period_s[0]) + 1   # more in a bin: a burst
        self._run_cap = p.run_cap or 1 << 30
        self._fixed = tanks is not None
        self._tanks: dict[str, TankWindow] = {}
        self.ignored = 0                            # contacts from unknown tanks/sensors
        self.unknown: set[tuple[str, str]] = set()
        for tank, sensors in (tanks or {}).items():
            ts = self._new_tank(tank)
            for s in sensors:
                ts.sensors[s] = Sensor(s, -math.inf, 0)

    # -- public -------------------------------------------------------------------------------
    def on_contact(self, t: float, tank: str, sensor: str):
        """One rising edge. Returns a sequence of events (usually the shared empty tuple)."""
        ts = self._tanks.get(tank)
        s = None if ts is None else ts.sensors.get(sensor)
        if s is None:
            s = self._unknown(t, tank, sensor)
            if s is None:
                return _NONE
            ts = self._tanks[tank]
        events = self._roll(ts, t) if t >= ts.bin_end else None
        s.n += 1
        s.last = t
        if s.state:
            if s.state == STUCK:
                return events or _NONE
            events = self._revive(ts, s, t, events)
        elif s.fast & SUSPECT_BINS == SUSPECT_BINS:
            return events or _NONE                  # fast for longer than a burst: stuck, not yet judged
        s.mark = ts.active
        if t - ts.prev_c >= RUN_GAP_S:              # a pause: a new run of contacts
            if ts.run_n == 2 and ts.run_cnt == 1 and self._run_cap < 1 << 30:
                self._pair(ts)                      # the run that ended was a pair: both count
            ts.tail = False
            ts.run_cur = ts.run_prev = ts.run_len = ts.run_n = ts.run_cnt = 0
            ts.run_t0 = t
        ts.run_n += 1
        ts.prev_c = t
        ts.raw += 1
        if ts.raw >= self._chatter:
            self._chatter_bin(ts)
        slot = math.floor(t * self._inv_slot)      # (floor: t may be negative, "start anywhere")
        if slot > ts.slot:
            ts.slot = slot
            ts.occ += 1
            ts.run_len += 1
            counted = not (ts.excl or ts.tail) and (ts.run_len <= ts.cap or t - ts.run_t0 >= BURST_S)
            if counted:
                ts.cur += 1
                ts.run_cur += 1
                ts.run_cnt += 1
            if counted and (ts.demanding or ts.vsum + ts.cur >= ts.k):
                events = self._decide(ts, t, events)
            elif ts.demanding and ts.osum + ts.occ < self.params.end_fraction * ts.k:
                self._drained(ts)
            if counted and not ts.demanding and ts.lsum + ts.cur >= ts.kp:
                events = self._persisting(ts, t, events)
            ts.last_t = t
        if (ts.beats.contact(t, ts.raw, ts.excl or ts.tail) and not ts.demanding
                and t - ts.last_raise >= self.params.repeat_s and ts.beats.found(t)):
            events = self._start(ts, t, events)       # a beat: regular fish, see demand_stats
        return events or _NONE

    def on_time(self, t: float) -> list:
        """Time has reached ``t``: close bins, end drained demands, judge silent sensors."""
        events: list = []
        for ts in self._tanks.values():
            if t >= ts.bin_end:
                events.extend(self._roll(ts, t) or ())
        return events

    def score(self, tank: str) -> tuple[float, int]:
        """(evidence, threshold) of a tank now, for status displays and tests."""
        ts = self._tanks[tank]
        return self._score(ts), ts.k

    @property
    def tanks(self):
        return self._tanks.keys()

    def sensor_state(self, tank: str, sensor: str) -> str:
        return ("healthy", "stuck", "dead")[self._tanks[tank].sensors[sensor].state]

    # -- evidence -----------------------------------------------------------------------------
    def _score(self, ts: TankWindow) -> float:
        total = ts.vsum + ts.cur
        m = ts.p1 + ts.p2 + ts.cur
        if ts.m_old > m:
            m = ts.m_old
        rest = total - m
        allowed = self.params.spike_gain * rest * 3.0 / (self._n - 3) + self.params.spike_allowance
        return rest + (m if m < allowed else allowed)

    def _decide(self, ts: TankWindow, t: float, events):
        """Raise, repeat or end a demand. Every raise also asks that this contact follow the one
        before it no later than the episode's own pace suggests: after fish stop, the next
        contact is turbulence, tens of seconds later, and must not be the one that raises."""
        score = self._score(ts)
        pace = self._n * self._bin / max(score, 1.0)          # mean gap between busy seconds
        p = self.params
        if not ts.demanding:
            if (score < ts.k or t - ts.last_t > RAISE_GAP_PACES * pace or t - ts.last_raise < p.repeat_s
                    or ts.raw > 3 * ts.occ + 1):             # a clump of contacts: chatter starting
                return events
            return self._start(ts, t, events)
        if ts.osum + ts.occ < p.end_fraction * ts.k:
            self._drained(ts)
            return events
        if t - ts.last_raise < p.repeat_s:
            return events
        recent = ts.recent
        if ts.fresh == 0:
            recent.clear()
        ts.fresh += 1
        recent.append(t)
        if len(recent) > p.repeat_contacts:
            del recent[0]
        if (len(recent) == p.repeat_contacts and score >= ts.k and not ts.excl and ts.raw <= 3 * ts.occ + 1
                and t - recent[-2 if len(recent) > 1 else 0] <= pace
                and t - recent[0] >= 0.5 * (len(recent) - 1) * pace      # not a burst's seconds
                and all(b - a <= 3.0 * pace for a, b in zip(recent, recent[1:], strict=False))):
            ts.last_raise, ts.fresh = t, 0
            return self._raise(ts, t, events)
        return events

    def _start(self, ts: TankWindow, t: float, events):
        ts.demanding, ts.last_raise, ts.fresh = True, t, 0
        self._unlearn_window(ts)
        return self._raise(ts, t, events)

    def _unlearn_window(self, ts: TankWindow) -> None:
        """The window that made a demand was the episode's start, not turbulence: take its
        (non-empty) spans back out of the background estimate."""
        ts.bg_t = max(ts.bg_n + 1.0, ts.bg_t - len(ts.vals))
        ts.cl_t = max(ts.cl_n + ts.cl_one + 1.0, ts.cl_t - len(ts.vals))

    def _raise(self, ts: TankWindow, t: float, events):
        """The rate: the window's contacts over the span that holds them (from the start of its
        oldest bin with contacts), so fish raised early in an episode are not reported slow."""
        n, start = len(ts.raws), ts.bin_end - self._bin
        for j in range(n):
            if ts.raws[(ts.head + j) % n]:
                start = ts.bin_end - self._bin * (n + 1 - j)
                break
        rate = (ts.rsum + (0 if ts.excl else ts.raw)) / max(t - start, self._bin)
        return [*(events or ()), Demand(ts.name, t, rate)]

    # -- sensors ------------------------------------------------------------------------------
    def _revive(self, ts: TankWindow, s: Sensor, t: float, events):
        s.state = HEALTHY
        return [*(events or ()), SensorRecovered(ts.name, s.name, t)]

    def _unknown(self, t: float, tank: str, sensor: str):
        if self._fixed:
            self.ignored += 1
            self.unknown.add((tank, sensor))
            return None
        ts = self._tanks.get(tank) or self._new_tank(tank)
        s = ts.sensors[sensor] = Sensor(sensor, t, ts.active)
        return s

    def _new_tank(self, tank: str) -> TankWindow:
        p = self.params
        t0 = PRIOR_S / p.bin_s                      # the prior: 15 min at the contract's bound
        lam0 = p.turbulence_max_hz * self._span
        ts = TankWindow(tank, self._n, 0, t0 * math.exp(-lam0), t0,
                        Beats(p.beat_window_s, p.beat_single_s, p.beat_period_s[0], p.beat_search_nodes,
                              self._beat_bin), self._persist_bins)
        # the clustering's prior: the same spans, their hits single (Poisson)
        ts.cl_n, ts.cl_one, ts.cl_t = ts.bg_n, t0 * lam0 * math.exp(-lam0), t0
        self._thresholds(ts)
        self._tanks[tank] = ts
        return ts
