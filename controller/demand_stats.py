"""The demand filter's statistics (see controller/demand.py): its two tests against turbulence,
the count and the beat, and the stuck and dead sensor tests.

*Count.* ``threshold``: the least number of busy seconds in the window whose upcrossing rate
under Poisson turbulence alone stays below the false-demand budget. ``caught_within`` and
``rate_for``: what such a count can catch of Poisson fish within the window from their first
contact, at a given threshold (the slow-fish limit, controller/demand.py *Slow fish*).

*Beat.* ``beat_chain``: is the contact at ``x0`` the latest of a *beat*, contacts one in each of
m + 1 consecutive cycles of a lattice ``φ - i·P`` (P in the period band), each within ±δ·P of
its lattice point, any other contacts in between ignored (turbulence interleaved with the
fish)? Position jitter of a beat (each contact moved by up to ±j·P) fits δ >= j; a pace whose
intervals vary by ±j drifts from any lattice like a random walk and fits δ ~ j over the ~10
cycles of a minute. A lattice fits a chain iff every pair (a, b), b - a cycles apart, has
``(b - a - 2δ)·P <= y_a - y_b <= (b - a + 2δ)·P``: each pair bounds P to an interval, so the
feasible periods of a chain are one interval [P_lo, P_hi], updated in O(m) per added point.
The search walks back from ``x0`` depth first (shortest first gap, then nearest the predicted
point), prunes chains that cannot reach λ even with a hit for every contact left, and stops
after ``cap`` candidates; a cycle whose window meets a span where a burst's contacts were
dropped may pass empty (no credit).

*Its false alarms.* A chain's surprise is ``S = m·(-log 2δ·P_hi·b)`` for m hits at turbulence b.
By Campbell's formula the expected number of m-chains ending at a Poisson contact with all
periods P <= B feasible is b^m × their volume, K_m·(2δB)^m: a box of 2δP per cycle, widened by
the phase and period the chain may choose (``chain_volume``; K_m ~ (m+1)^1.7/δ by Monte Carlo).
S >= λ needs P_hi <= P_m = e^(-λ/m)/2δb, so ``beat_tail`` = Σ_m K_m·min(e^-λ, (2δbB)^m) bounds
the chance that turbulence ends a chain of S >= λ, and ``beat_threshold`` solves it for the
per-contact share of the budget: λ ~ 18 at b = 0.05, ~14 at b = 0.01 (0.05 a day; ~24 and ~21 at
1e-4). Checked by simulation:
over 8,000 days of Poisson contacts at 0.05 /s (δ = 0.15, P to 12 s) chains reached S >= 16,
18, 20, 22 after 180, 31, 4, 2 distinct clusters of contacts, where the bound allows 1,026,
174, 32, 5; in the filter (bursts, clumps, estimated turbulence) with the beat's budget raised
to 0.3 and 3 a day, 200 tank-days at 0.02-0.05 /s gave 0.045 and 0.6-0.66 false beats a day.
"""
from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from functools import lru_cache

DAY_S = 86400.0
MAX_SKIPS = 2           # a burst (< 10 s) hides at most two cycles of a beat at 5 s; more is a chain
                        # strung across bursts (with a window of minutes, bursts gave free cycles)
HEALTHY, STUCK, DEAD = 0, 1, 2


def threshold(b_hz: float, window_s: float, per_day: float, k_min: int) -> int:
    """Least k ≥ k_min whose sliding-window upcrossing rate under Poisson(b) is ≤ per_day."""
    mean = b_hz * window_s
    k = k_min
    while DAY_S * b_hz * math.exp((k - 1) * math.log(mean) - mean - math.lgamma(k)) > per_day:
        k += 1
    return k


CLUSTER_SHARES = (0.6, 0.4)     # a cluster past one busy second: two, three (a wave's hits); longer
                                # clumps are the burst and persistence rules' (one counts ~2 at most alone)


def cluster_mean(single: float) -> float:
    """The model's mean busy seconds a cluster."""
    return sum(s * q for s, q in enumerate(cluster_sizes(single)))


def cluster_sizes(single: float) -> list[float]:
    """The model's pmf of a turbulence cluster's busy seconds (index 0 unused): one with
    probability ``single``, else two or three (``CLUSTER_SHARES``)."""
    return [0.0, single, *((1.0 - single) * q for q in CLUSTER_SHARES)]


@lru_cache(maxsize=4096)
def clustered_threshold(b_hz: float, window_s: float, per_day: float, k_min: int, single: float) -> int:
    """``threshold`` for turbulence in clusters: clusters arrive at ``b_hz`` (what the share of empty
    spans measures), each of ``cluster_sizes(single)`` busy seconds. A cluster of s lifts the window's
    count X across k when k - s <= X < k; X (what an arriving cluster sees, Poisson arrivals) is
    compound Poisson(b·window), its pmf by Panjer's recursion. ``single`` 1 is ``threshold``."""
    if single >= 1.0:
        return threshold(b_hz, window_s, per_day, k_min)
    sizes, lam = cluster_sizes(single), b_hz * window_s
    weighted = [s * q for s, q in enumerate(sizes)]
    pmf, cdf = [math.exp(-lam)], [math.exp(-lam)]

    def upto(j: int) -> float:                 # P[X <= j], the pmf grown as far as asked
        while len(pmf) <= j:
            n = len(pmf)
            pmf.append(lam / n * sum(weighted[s] * pmf[n - s] for s in range(1, min(n, len(sizes) - 1) + 1)))
            cdf.append(cdf[-1] + pmf[-1])
        return cdf[j] if j >= 0 else 0.0

    k = max(k_min, math.ceil(lam * sum(weighted)) + 1)     # below its mean the count seldom crosses up
    while DAY_S * b_hz * sum(q * (upto(k - 1) - upto(k - 1 - s)) for s, q in enumerate(sizes) if q) > per_day:
        k += 1
    return k


def caught_within(rate_hz: float, k: int, window_s: float) -> float:
    """P[a Poisson episode at ``rate_hz`` holds >= k contacts in the window from its first]:
    1 + Poisson(rate × window) >= k (turbulence's own contacts ignored: a lower bound)."""
    mean = rate_hz * window_s
    term = cdf = math.exp(-mean)
    for i in range(1, k - 1):
        term *= mean / i
        cdf += term
    return 1.0 - cdf if k > 1 else 1.0


def rate_for(recall: float, k: int, window_s: float) -> float:
    """The slowest Poisson rate whose episodes reach k contacts in the window with ``recall``."""
    lo, hi = 0.0, 10.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if caught_within(mid, k, window_s) < recall else (lo, mid)
    return hi


def chain_volume(m: int, jitter: float) -> float:
    """K_m: the volume of m-point chains within ±δP of some lattice through a fixed point, for
    all periods up to P, in units of (2δP)^m. Monte Carlo gives 13.2, 34.7, 66.6, 160 (m = 4, 8,
    12, 20; δ = 0.15) and ~ 1/δ × that for δ in [0.1, 0.45]; this bounds them all (m <= 30)."""
    return 0.2 / jitter * (m + 1) ** 1.7


def beat_tail(lam: float, jitter: float, b_hz: float, p_min: float, p_max: float) -> float:
    """Bound on the expected number of chains ending at a turbulence contact with S >= λ and a
    period in [p_min, p_max]: an m-chain needs P_hi <= P_m = e^(-λ/m) / 2δb."""
    total, two_db = 0.0, 2.0 * jitter * b_hz
    for m in range(1, 64):
        p_m = math.exp(-lam / m) / two_db
        if p_m > p_min:
            total += chain_volume(m, jitter) * min(math.exp(-lam), (two_db * p_max) ** m)
    return total


@lru_cache(maxsize=4096)
def beat_threshold(b_hz: float, jitter: float, per_day: float, levels: int, p_min: float,
                   p_max: float) -> float:
    """λ: ``per_day`` false beats per tank-day, shared by ``levels`` tolerances, over the
    b x 86,400 contacts a day that can each end a chain (bisection on ``beat_tail``)."""
    q = per_day / (levels * DAY_S * b_hz)
    lo, hi = 0.0, 200.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if beat_tail(mid, jitter, b_hz, p_min, p_max) > q else (lo, mid)
    return hi


def beat_tests(b_hz: float, jitters, per_day: float, period_s: tuple[float, float], window_s: float,
               scale: float = 1.0):
    """((δ, log 2δb, λ, longest period) per tolerance δ, fewest hits that could reach λ) at
    turbulence b. A beat of period P needs λ / -log(2δbP) hits, all within the window: slower
    beats cannot be confirmed in time and are not searched for, nor counted in λ's bound.
    ``scale``: λ times this, for turbulence in clusters of that many contacts on average (a wave's
    hits a few seconds apart are cycles of a beat for free: the bound counts independent arrivals)."""
    tests, least = [], 1 << 30
    p_min, p_max = period_s
    grid = [p_min * (p_max / p_min) ** (i / 64) for i in range(65)]
    for d in jitters:
        log_2db = math.log(2.0 * d * b_hz)
        lam = scale * beat_threshold(b_hz, d, per_day, len(jitters), p_min, p_max)
        fits = [q for q in grid if -(log_2db + math.log(q)) * (window_s / q + 2 * d) >= lam]
        if not fits:
            continue
        longest = grid[len(fits)] if len(fits) < len(grid) else p_max
        lam = scale * beat_threshold(b_hz, d, per_day, len(jitters), p_min, longest)
        tests.append((d, log_2db, lam, longest))
        least = min(least, math.ceil(lam / -(log_2db + math.log(p_min))))
    return tuple(tests), least


class Beats:
    """One tank's beat test: its recent *single* contacts (none other within ``single_s``: a
    fish bump is one contact, a burst several) outside bursty bins, and the spans bursts took."""

    __slots__ = ("times", "gaps", "prev", "tests", "least", "window", "single", "p_min", "nodes",
                 "bin_max")

    def __init__(self, window_s: float, single_s: float, p_min: float, nodes: int, bin_max: int):
        self.times: list[float] = []
        self.gaps: list[tuple[float, float]] = []   # (start, end) of spans whose contacts went
        self.prev = -math.inf                       # the tank's last contact
        self.tests: tuple = ()                      # from beat_tests, for the tank's turbulence
        self.least = 1 << 30
        self.window, self.single, self.p_min, self.nodes, self.bin_max = (
            window_s, single_s, p_min, nodes, bin_max)

    def contact(self, t: float, in_bin: int, excluded: bool) -> bool:
        """Record a contact, the ``in_bin``-th of its bin; True if it may end a beat."""
        prev, self.prev = self.prev, t
        if t - prev < self.single:                  # a clump: neither contact is a beat's
            times, gaps = self.times, self.gaps
            if times and times[-1] == prev:
                times.pop()
            if gaps and gaps[-1][1] >= prev:
                gaps[-1] = (gaps[-1][0], t)
            else:
                gaps.append((prev, t))
            return False
        if in_bin > self.bin_max or excluded:
            return False
        self.times.append(t)
        return in_bin < self.bin_max and len(self.times) > self.least

    def found(self, t: float) -> bool:
        """Does the contact at ``t`` (the last recorded) end a beat that clears λ?"""
        times = self.times
        hi = len(times) - 1
        lo = bisect_left(times, t - self.window, 0, hi)
        if hi - lo < self.least:
            return False
        return any(beat_chain(times, lo, hi, t, d, log_2db, lam, self.p_min, p_max, self.nodes, self.gaps)
                   for d, log_2db, lam, p_max in self.tests)

    def forget(self, since: float, until: float) -> None:
        """The contacts from ``since`` on were a burst's: drop them, remember the span."""
        times, gaps = self.times, self.gaps
        while times and times[-1] >= since:
            times.pop()
        while gaps and gaps[-1][1] >= since:
            since = min(since, gaps.pop()[0])
        gaps.append((since, until))

    def trim(self, old: float) -> None:
        """Drop what lies before ``old``: no chain reaches back there."""
        times = self.times
        if times and times[0] < old:
            del times[:bisect_left(times, old)]
        if self.gaps and self.gaps[0][1] < old:
            self.gaps = [g for g in self.gaps if g[1] >= old]


def beat_chain(times: list[float], lo: int, hi: int, x0: float, jitter: float, log_2db: float,
               lam: float, p_min: float, p_max: float, cap: int, gaps=()) -> bool:
    """Is ``x0`` the end of a beat of surprise >= ``lam``? ``times[lo:hi]``: earlier contacts,
    sorted; ``log_2db`` = log(2·δ·b); ``gaps``: (start, end) spans whose contacts were dropped
    as bursts: a cycle whose window meets one may pass empty (it adds nothing to S)."""
    search = _Search(times, lo, x0, 2.0 * jitter, log_2db, lam, cap, gaps)
    return search.extend(1, p_min, p_max, hi)


class _Search:
    __slots__ = ("times", "lo", "x0", "two_d", "log_2db", "lam", "left", "gaps", "ys", "cycles", "skips")

    def __init__(self, times, lo, x0, two_d, log_2db, lam, cap, gaps):
        self.times, self.lo, self.x0, self.two_d = times, lo, x0, two_d
        self.log_2db, self.lam, self.left, self.gaps = log_2db, lam, cap, gaps
        self.ys, self.cycles = [x0], [0]             # the chain: times and their cycles
        self.skips = MAX_SKIPS                       # empty cycles a chain may pass across bursts

    def extend(self, m: int, p_lo: float, p_hi: float, hi: int) -> bool:
        """Find the chain's point m cycles before x0 in ``times[lo:hi]``; True once S >= λ."""
        times, ys, cycles, two_d = self.times, self.ys, self.cycles, self.two_d
        y1, k = ys[-1], m - cycles[-1]
        first = max(y1 - (k + two_d) * p_hi, self.x0 - (m + two_d) * p_hi)
        last = min(y1 - (k - two_d) * p_lo, self.x0 - (m - two_d) * p_lo)
        j = bisect_right(times, last, self.lo, hi)
        i = bisect_left(times, first, self.lo, j)
        if m == 1:                                  # the shortest gap first: the fundamental,
            order = range(j - 1, i - 1, -1)         # not a multiple of the period
        elif j - i <= 1:
            order = range(i, j)
        else:
            pred = y1 - 0.5 * k * (p_lo + p_hi)
            order = sorted(range(i, j), key=lambda q: abs(times[q] - pred))
        hits = len(ys)                              # with the new point
        for q in order:
            self.left -= 1
            if self.left < 0:
                return False
            y = times[q]
            lo_p, hi_p = p_lo, p_hi
            for ya, c in zip(ys, cycles, strict=True):   # every pair with the new point bounds P
                d, n = ya - y, m - c
                v = d / (n + two_d)
                if v > lo_p:
                    lo_p = v
                v = d / (n - two_d)
                if v < hi_p:
                    hi_p = v
            if lo_p > hi_p:
                continue
            if -hits * (self.log_2db + math.log(hi_p)) >= self.lam:
                return True
            # prune: even a hit for every remaining contact or lattice point back to the
            # oldest contact, at the shortest period left, cannot reach λ
            more = min(q - self.lo, int((y - times[self.lo]) / lo_p + two_d))
            if -(hits + more) * (self.log_2db + math.log(lo_p)) < self.lam:
                continue
            ys.append(y)
            cycles.append(m)
            if self.extend(m + 1, lo_p, hi_p, q):
                return True
            ys.pop()
            cycles.pop()
        if (self.gaps and first < last and self.left > 0 and self.skips > 0
                and any(a < last and b > first for a, b in self.gaps)):
            self.left -= 1                          # this cycle's contact may have been a burst's
            self.skips -= 1
            if self.extend(m + 1, p_lo, p_hi, hi):
                return True
            self.skips += 1
        return False


class Sensor:
    __slots__ = ("name", "n", "last", "mark", "state", "fast", "seen", "busy", "quiet", "held")

    def __init__(self, name: str, t: float, mark: int):
        self.name, self.n, self.last, self.mark, self.state, self.fast = name, 0, t, mark, HEALTHY, 0
        self.seen = 0.0
        self.busy = self.quiet = 0          # bins in a row it fired in, or was silent in
        self.held = False                   # stuck by firing longer than any episode (not by its rate)


LONG_BUSY_BINS = 24         # a sensor firing in every bin for 2 min: its bins are no evidence of the others' death
EPISODE_MAX_S = 600.0       # the contract's longest fish episode: a sensor firing in every bin for
                            # longer is stuck, whatever its rate (one at a fixed 1-2.5 /s for an hour,
                            # under the fast test's 3 /s, was fed every 2 min, its healthy neighbour
                            # reported dead; fish fill every bin of 5 s only from ~0.5 /s a sensor)


SHARE_TAU_S = 6 * 3600.0    # a sensor's share of its tank's active bins: learned over hours
SHARE_PRIOR = 120.0         # active bins of prior (~10 min), shared equally: a new sensor is no outlier


class SensorTests:
    """Stuck and dead sensors, judged as each bin closes (see controller/demand.py, *Faults*).
    ``Sensor.n``: its contacts in the bin; ``fast``: one bit per recent bin, set when the bin was
    stuck-fast; ``mark``: the tank's active-bin count at its last contact; ``seen``: the active
    bins it fired in (decaying over ``SHARE_TAU_S``, as the tank's own count ``active_ew``)."""

    def __init__(self, p):
        self.stuck_n = max(2, math.floor(0.9 * p.stuck_rate_hz * p.bin_s))
        self.bins = max(1, round(p.stuck_window_s / p.bin_s))
        self.need = max(1, math.ceil(p.stuck_share * self.bins))
        self.recover_mask = (1 << max(1, round(p.recover_s / p.bin_s))) - 1
        self.dead_after_s, self.dead_active_bins = p.dead_after_s, p.dead_active_bins
        self.log_dead_p = math.log(p.dead_p)
        self.decay = math.exp(-p.bin_s / SHARE_TAU_S)
        # 15 min of bins: an episode of 10 min held between ramps of 1.5 min each up and down (the
        # bench's ramped fish) fired a sensor in every bin for 13 min, and was called stuck at 11
        self.held_bins = math.ceil(1.5 * EPISODE_MAX_S / p.bin_s)
        self.recover_bins = max(1, round(p.recover_s / p.bin_s))

    def judge(self, sensors: dict, active: int, active_ew: float, bin_active: bool, t: float,
              bins: int) -> list | None:
        """[(sensor, "stuck" | "dead" | None for recovered)] as the bin closes, followed by
        ``bins - 1`` empty ones, or None; ``active``: the tank's bins with healthy contacts, this
        one included if ``bin_active``; ``active_ew``: the same, decaying."""
        out = None
        full = (1 << self.bins) - 1
        shift = min(bins - 1, self.bins)
        decay = self.decay ** bins
        for s in sensors.values():
            s.seen = s.seen * decay + (bin_active and s.n > 0)
            s.fast = ((((s.fast << 1) | (s.n >= self.stuck_n)) << shift) & full)
            if s.n > 0:
                s.busy, s.quiet = (s.busy + 1, 0) if bins == 1 else (1, 0)
            else:
                s.busy, s.quiet = 0, s.quiet + bins
            s.n = 0
            if s.state == HEALTHY:
                if s.fast.bit_count() >= self.need or s.busy >= self.held_bins:
                    s.state, s.held = STUCK, s.fast.bit_count() < self.need
                    out = [*(out or ()), (s.name, "stuck")]
                elif (len(sensors) > 1 and t - s.last >= self.dead_after_s
                      and active - s.mark >= self.dead_active_bins
                      and (active - s.mark) * math.log1p(-self._share(s, active_ew, len(sensors)))
                      < self.log_dead_p):
                    s.state = DEAD
                    out = [*(out or ()), (s.name, "dead")]
            elif s.state == STUCK and not (s.fast & self.recover_mask) and (not s.held or
                                                                             s.quiet >= self.recover_bins):
                s.state, s.mark, s.held, s.busy = HEALTHY, active, False, 0
                out = [*(out or ()), (s.name, None)]
        return out

    @staticmethod
    def _share(s: Sensor, active_ew: float, n: int) -> float:
        """The share of the tank's active bins it fires in (a dead spell lowers it slowly)."""
        return min(0.999, (s.seen + SHARE_PRIOR / n) / (active_ew + SHARE_PRIOR))
