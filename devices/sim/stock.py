"""The fish of a simulated tank as individuals: they grow on the food they eat and die at a known
rate — the ground truth a grow-out run's surveys, rations and production figures are judged by.

Growth: every gram of food that reaches the tank is eaten, and ``fcr`` grams of food make one gram
of fish (the biological feed conversion ratio). A meal's gain is shared among the fish in
proportion to ``w_i · k_i``: each fish's weight ``w_i`` times its own growth factor ``k_i`` (drawn
once, lognormal, sd ``growth_cv_pct``), so the stock keeps its specific growth rate on average while
its sizes spread — slowly, as a real cohort's do (what grading is for). Mortality: each fish dies
with probability ``1 − exp(−m·dt)`` over ``dt`` days at ``mortality_pct_day`` = 100·m.

A tank of 20,000 fish is followed through a sample of at most ``sample`` individuals standing for
the whole count (each is ``count / sample`` fish): the weights a camera sees are drawn from it. The
count itself is exact: deaths are drawn for the whole count, and the same share of the sample goes.
Deaths are written to the truth log (``mortality``: tank, count) as a farm worker would count them,
and a ``stock`` record closes every farm day, or every ``record_s`` (count, biomass, mean and CV of
weight, food eaten, deaths and the weight they had: ``eaten_g`` over the gain of the biomass plus
``died_g`` is ``fcr``, the biological ratio; over the biomass's gain alone, the net one).
"""
from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

DAY_S = 86400.0


class SimStockParams(BaseModel):
    """farm.toml ``[sim.stock]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    fcr: float = Field(1.4, gt=0.3, le=10, description="food eaten / weight gained (biological)")
    mortality_pct_day: float = Field(0.05, ge=0, le=20, description="daily deaths, % of the count")
    weight_cv_pct: float = Field(20.0, ge=0, le=100, description="spread of the weights at the start")
    growth_cv_pct: float = Field(10.0, ge=0, le=100, description="spread of the fish's own growth factors")
    sample: int = Field(2000, ge=10, le=200_000, description="individuals followed")
    step_s: float = Field(3600.0, gt=0, le=DAY_S, description="farm s between mortality draws")
    record_s: float = Field(DAY_S, gt=0, le=DAY_S, description="farm s between the truth log's stock records")


class SimStock:
    """One tank's fish; ``t0`` the farm time the config's count and mean weight hold."""

    def __init__(self, tank_id: str, count: int, mean_weight_g: float, params: SimStockParams,
                 rng: np.random.Generator, t0: float, truth=None):
        self.id, self.p, self.rng, self.truth = tank_id, params, rng, truth
        self.count = int(count)
        n = max(1, min(params.sample, self.count))
        sd = math.sqrt(math.log1p((params.weight_cv_pct / 100.0) ** 2))
        w = rng.lognormal(-sd * sd / 2, sd, n)
        self.w = mean_weight_g * w / w.mean()                     # exactly the config's mean at t0
        g = math.sqrt(math.log1p((params.growth_cv_pct / 100.0) ** 2))
        self.k = rng.lognormal(-g * g / 2, g, n)
        self.t = t0
        self.period = math.floor(t0 / params.record_s)
        self.eaten_g = 0.0                                        # since t0
        self.deaths = 0
        self.died_g = 0.0           # since t0: the dead fish's weight when they died (what the food
                                    # had made of them too: the biological FCR's share of the gain)

    # -- what the world does to it ------------------------------------------------------------
    def feed(self, grams: float, t: float) -> None:
        """``grams`` reach the tank at ``t`` and are eaten."""
        self.advance(t)
        if grams <= 0 or self.count == 0:
            return
        self.eaten_g += grams
        share = self.w * self.k
        # the sample stands for the count: per sampled fish, count / n fish share the gain
        self.w += (grams / self.p.fcr) * share / share.sum() * len(self.w) / self.count

    def advance(self, t: float) -> None:
        """Mortality (and the day's records) up to ``t``."""
        while self.t < t:
            step = min(self.p.step_s, self.p.record_s)
            end = min(t, (math.floor(self.t / step) + 1) * step)
            self._deaths(end - self.t, end)
            self.t = end
            period = math.floor(end / self.p.record_s)
            if period != self.period:
                self.period = period
                self._record(end)

    @property
    def w(self) -> np.ndarray:
        """The sampled fish's weights, g."""
        return self._w

    @w.setter
    def w(self, value: np.ndarray) -> None:
        # the fish change only when fed or when some die: their mean is asked for each time the
        # simulator looks ahead for the next episode (every 5 ms of wall, for every tank)
        self._w, self._mean = value, None

    # -- what a camera and a judge see -------------------------------------------------------
    @property
    def mean_g(self) -> float:
        if self._mean is None:
            self._mean = float(self._w.mean()) if self.count else 0.0
        return self._mean

    @property
    def biomass_g(self) -> float:
        return self.count * self.mean_g

    def weights(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` fish drawn at random (with replacement: a camera may see one fish twice)."""
        return self.w[rng.integers(0, len(self.w), n)] if self.count else np.empty(0)

    def _deaths(self, dt_s: float, t: float) -> None:
        if self.p.mortality_pct_day <= 0 or self.count == 0 or dt_s <= 0:
            return
        q = -math.expm1(-self.p.mortality_pct_day / 100.0 * dt_s / DAY_S)
        dead = int(self.rng.binomial(self.count, q))
        if not dead:
            return
        self.died_g += dead * self.mean_g                 # deaths strike at random, whatever the size
        gone = self.rng.random(len(self.w)) < dead / self.count    # the same share of the sample
        if gone.all():
            gone[self.rng.integers(len(self.w))] = False
        self.w, self.k = self.w[~gone], self.k[~gone]
        self.count -= dead
        self.deaths += dead
        if self.truth is not None:
            self.truth.write("mortality", t, tank=self.id, count=dead)

    def _record(self, t: float) -> None:
        if self.truth is not None:
            cv = float(self.w.std() / self.w.mean() * 100) if self.count else 0.0
            self.truth.write("stock", t, tank=self.id, count=self.count, biomass_g=round(self.biomass_g, 1),
                             mean_g=round(self.mean_g, 3), cv_pct=round(cv, 2), eaten_g=round(self.eaten_g, 1),
                             deaths=self.deaths, died_g=round(self.died_g, 1))
