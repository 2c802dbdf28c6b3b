"""The demand filter's thresholds (controller/demand.py, *The threshold* and *Clusters*): the tank's
turbulence from its shares of empty and single spans, and the count's and beat's thresholds for
it, on the grid the filter precomputes (clustered levels computed once, when first needed)."""
from __future__ import annotations

import bisect
import math

from controller.demand_stats import beat_tests, caught_within, cluster_mean, clustered_threshold, rate_for
from controller.demand_window import TankWindow

PRIOR_S = 900.0         # the background prior: this long at the contract's bound (turbulence_max_hz)
SINGLE_LEVELS = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0)  # clustering grid: share of single clusters
CLUSTER_TAU_FACTOR = 4.0   # the clustering is measured over 4x background_tau_s: a slower property, and
                           # its upper bound's margin halves (1-3 hits read at 0.5 over the 2 h, not 1/3)
SINGLE_Z = 2.0          # the clustering's estimate is taken at its upper bound: Poisson reads ~1 ± noise


class Thresholds:
    """Mixin of DemandFilter: ``params``, ``_b_grid``, ``_k_grid``, ``_kp_grid``, ``_beats``,
    ``_k_at``, ``_beat_at``, ``_bin``, ``_span``, ``_window``, ``_persist``, ``_run_cap``, ``_tanks`` are its."""

    def _background(self, ts: TankWindow) -> float:
        """From the share of empty spans (the window's complete bins): e^(-b·span) under Poisson
        turbulence, its lower confidence bound (one s.d., spans a window apart independent)."""
        share, n_eff = ts.bg_n / ts.bg_t, max(1.0, ts.bg_t / len(ts.vals))
        lo = share - math.sqrt(share * (1.0 - share) / n_eff) - 0.5 / n_eff
        b = -math.log(max(lo, 1e-9)) / self._span
        if ts.bg_seen * self._bin < PRIOR_S:
            # the prior alone is the contract's bound, not its lower confidence bound: 15 min of pseudo
            # spans at 0.05 /s bound b at the grid's top (4x), k ~26 busy seconds a minute, and every
            # episode in a tank's first minutes after a (re)start went unraised below ~0.5 /s
            b = min(b, self.params.turbulence_max_hz)
        return min(max(self.params.turbulence_floor_hz, b), self._b_grid[-1])

    def _thresholds(self, ts: TankWindow) -> None:
        """The tests' thresholds from the tank's turbulence, rounded up on the grid."""
        i = min(63, bisect.bisect_left(self._b_grid, self._background(ts)))
        prior = ts.bg_seen * self._bin < PRIOR_S
        j = 0 if prior else self._clustering(ts)
        key = i + 64 * (j + len(SINGLE_LEVELS) * prior)
        if key != ts.grid_i:
            ts.grid_i = key
            ts.k, ts.kp = self._count_thresholds(i, j)
            ts.cap = max(self._run_cap, ts.k // 4) if self.params.run_cap else 1 << 30
            window, grid = self._beats[prior]
            ts.beats.window = window
            ts.beats.tests, ts.beats.least = grid[i] if j == 0 else self._clustered_beats(i, j)

    def _clustering(self, ts: TankWindow) -> int:
        """Where the tank's turbulence lies on ``SINGLE_LEVELS``: the share of its clusters that hold
        one busy second. Under turbulence in clusters at rate c, each of one busy second with
        probability q, a span holds none with probability e^-λ and exactly one with λq·e^-λ (λ = c ×
        span): q from the shares of empty and single spans, which (like the empty share) hardly move
        when undetected slow fish pass (their spans hold several). Waves hitting a sensor two or three
        times, 1–3 s apart, at 0.03 /s gave 73 false demands a day at the Poisson threshold."""
        if ts.cl_n <= 0.0 or ts.cl_n >= ts.cl_t:
            return 0
        empty, one = ts.cl_n / ts.cl_t, ts.cl_one / ts.cl_t
        lam = -math.log(empty)
        if lam < 1e-6:
            return 0
        # its upper confidence bound: on a calm tank few spans hold anything, and a share of single
        # ones read at ~0.7 set Poisson tanks' thresholds up (the bench's slowest fish lost 5 %)
        n_eff = max(1.0, ts.cl_t / len(ts.vals))
        single = (one + SINGLE_Z * math.sqrt(one * (1.0 - one) / n_eff) + 0.5 / n_eff) / (lam * empty)
        return next((j for j, level in enumerate(SINGLE_LEVELS) if level <= single), len(SINGLE_LEVELS) - 1)

    def _clustered_beats(self, i: int, j: int):
        """The beat's tests at ``_b_grid[i]`` for turbulence in clusters (``SINGLE_LEVELS[j]``)."""
        got = self._beat_at.get((i, j))
        if got is None:
            p = self.params
            got = self._beat_at[(i, j)] = beat_tests(self._b_grid[i], p.beat_jitter, p.beat_false_alarms_per_day,
                                                     p.beat_period_s, p.beat_window_s,
                                                     cluster_mean(SINGLE_LEVELS[j]))
        return got

    def _count_thresholds(self, i: int, j: int) -> tuple[int, int]:
        """(k, kp) at background ``_b_grid[i]`` and clustering ``SINGLE_LEVELS[j]``."""
        if j == 0:
            return self._k_grid[i], self._kp_grid[i]
        got = self._k_at.get((i, j))
        if got is None:
            p, b, single = self.params, self._b_grid[i], SINGLE_LEVELS[j]
            k = clustered_threshold(b, self._window, p.false_alarms_per_day, p.min_contacts, single)
            kp = (clustered_threshold(b, self._persist, p.persist_false_alarms_per_day,
                                      max(p.min_contacts, math.ceil(b * self._persist) + 1), single)
                  if self._persist else 1 << 30)
            got = self._k_at[(i, j)] = (k, kp)
        return got

    def slow_fish(self, tank: str) -> str | None:
        """A note when the tank's measured turbulence makes its slowest fish (``slow_fish_hz``,
        Poisson) more likely missed than served within the window, else None (see *Slow fish*)."""
        ts = self._tanks[tank]
        if ts.bg_t * self._bin < self.params.learn_s + 900.0:
            return None                             # still measuring (the prior is the worst case)
        p = self.params
        recall = caught_within(p.slow_fish_hz, ts.k, self._window)
        if recall >= p.slow_fish_recall:
            return None
        return (f"turbulence {self._background(ts):.3f}/s: fish at {p.slow_fish_hz:g}/s served within "
                f"{self._window:.0f} s only {recall:.0%} of the time; at 99 % from "
                f"{rate_for(0.99, ts.k, self._window):.2f}/s")
