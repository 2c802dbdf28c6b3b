"""Feeding tables: % of body weight a day by weight class and water temperature, the pellet for
each class and, where the chart gives it, the growth to expect — loaded by the operator from their
feed maker's chart, with a required ``source``; and the day's ration a weight survey's fish call for.

A table file (TOML)::

    species = "sparus_aurata"
    source = "..."                      # required: whose chart, which edition
    temperatures_c = [14, 18, 22, 26]   # strictly increasing
    [[classes]]                         # in order of weight
    up_to_g = 5                         # the class holds fish lighter than this
    pellet_mm = 0.8
    rate_pct = [2.0, 3.5, 5.0, 5.5]     # % of body weight a day, one per temperature
    sgr_pct = [1.5, 3.0, 4.5, 5.0]      # optional: specific growth rate to expect, %/day

Between listed temperatures rates are linear in temperature; beyond the first or last, the nearest
column's (a chart says nothing past its range: a cold cut-off is a column of zeros). A fish heavier
than the last class's ``up_to_g`` is fed as the last class.

A survey's ration feeds each measured fish by its own class: with n fish of weights w_i in a tank
of N, ration = N/n · Σ w_i · rate(w_i, T) / 100. A mean-weight ration (N · mean · rate(mean))
misfeeds a spread stock whose classes straddle a rate step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from controller.config import load_toml, validate_section

PELLET_QUANTILE = 0.25     # the pellet suits the smallest quarter of the fish: they must take it


class FeedingClass(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    up_to_g: float = Field(gt=0)
    pellet_mm: float = Field(gt=0, le=50)
    rate_pct: list[float] = Field(min_length=1, description="% body weight a day, one per temperature")
    sgr_pct: list[float] | None = Field(None, description="expected specific growth rate, %/day, per temperature")

    @model_validator(mode="after")
    def _ranges(self):
        if any(not 0 <= r <= 20 for r in self.rate_pct):
            raise ValueError(f"rate_pct must lie in 0..20 % a day, not {self.rate_pct}")
        if self.sgr_pct is not None and any(not -5 <= g <= 20 for g in self.sgr_pct):
            raise ValueError(f"sgr_pct must lie in -5..20 % a day, not {self.sgr_pct}")
        return self


class FeedingTable(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    species: str = Field(min_length=1)
    source: str = Field(min_length=1, description="whose chart, which edition: required")
    temperatures_c: list[float] = Field(min_length=1)
    classes: list[FeedingClass] = Field(min_length=1)

    @model_validator(mode="after")
    def _shape(self):
        if not self.source.strip():
            raise ValueError("source must name where the table comes from")
        t = self.temperatures_c
        if any(not -5 <= x <= 40 for x in t) or any(b <= a for a, b in zip(t, t[1:], strict=False)):
            raise ValueError(f"temperatures_c must increase strictly within -5..40 degC, not {t}")
        ups = [c.up_to_g for c in self.classes]
        if any(b <= a for a, b in zip(ups, ups[1:], strict=False)):
            raise ValueError(f"classes' up_to_g must increase strictly, not {ups}")
        for i, c in enumerate(self.classes):
            for name in ("rate_pct", "sgr_pct"):
                values = getattr(c, name)
                if values is not None and len(values) != len(t):
                    raise ValueError(f"classes.{i}.{name} has {len(values)} values for {len(t)} temperatures")
        return self

    # -- lookups (vectorised over weights) ---------------------------------------------------------
    def class_index(self, weight_g) -> np.ndarray:
        ups = np.array([c.up_to_g for c in self.classes])
        return np.minimum(np.searchsorted(ups, np.asarray(weight_g, float), side="right"), len(ups) - 1)

    def rate_pct(self, weight_g, temp_c: float) -> np.ndarray:
        """% of body weight a day for fish of ``weight_g`` (scalar or array) in water at ``temp_c``."""
        per_class = np.array([np.interp(temp_c, self.temperatures_c, c.rate_pct) for c in self.classes])
        return per_class[self.class_index(weight_g)]

    def pellet_mm(self, weight_g) -> np.ndarray:
        return np.array([c.pellet_mm for c in self.classes])[self.class_index(weight_g)]

    def sgr_pct(self, weight_g: float, temp_c: float) -> float | None:
        c = self.classes[int(self.class_index(weight_g))]
        return None if c.sgr_pct is None else float(np.interp(temp_c, self.temperatures_c, c.sgr_pct))


def load_feeding_table(path: str | Path) -> FeedingTable:
    """A table file; BadInput names the file and the key at fault."""
    return validate_section(FeedingTable, load_toml(path), str(path))


def table_from_species(key: str, species) -> FeedingTable:
    """The species file's own rows (no temperature: one column) as a table, for a species the
    operator has loaded no chart for."""
    return FeedingTable(species=key, source=species.source or f"config/species.toml [{key}]",
                        temperatures_c=[20.0],
                        classes=[FeedingClass(up_to_g=r.up_to_g, pellet_mm=r.pellet_mm, rate_pct=[r.rate_pct])
                                 for r in species.feeding])


@dataclass(frozen=True)
class RationPlan:
    grams: float               # a day, for the whole tank
    biomass_g: float           # stock x mean weight
    mean_weight_g: float
    rate_pct: float            # grams / biomass, % a day: the tank's effective rate
    pellet_mm: float
    pellet_share: float        # fraction of the fish whose own class takes that pellet


def ration_from_weights(weights_g, stock: int, temp_c: float, table: FeedingTable) -> RationPlan:
    """The day's ration for ``stock`` fish of which ``weights_g`` (n >= 1, grams) were measured."""
    w = np.asarray(weights_g, float).ravel()
    if w.size == 0 or not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise ValueError("a ration needs at least one measured fish, every weight positive and finite")
    if stock < 0:
        raise ValueError(f"stock of {stock} fish")
    mean = float(w.mean())
    grams = stock * float(np.mean(w * table.rate_pct(w, temp_c))) / 100.0
    pellet = float(table.pellet_mm(np.quantile(w, PELLET_QUANTILE, method="inverted_cdf")))   # a fish's weight
    share = float(np.mean(table.pellet_mm(w) == pellet))
    biomass = stock * mean
    return RationPlan(grams, biomass, mean, 100.0 * grams / biomass if biomass > 0 else 0.0, pellet, share)


def project_weight(weight_g: float, days: float, temp_c: float, table: FeedingTable,
                   sgr_pct: float | None = None) -> float | None:
    """The mean weight ``days`` on, growing day by day at ``sgr_pct`` (measured between surveys) or
    else at the table's expected SGR for the weight reached; None when neither is known."""
    if days < 0 or not math.isfinite(days):
        raise ValueError(f"days must be >= 0 and finite, not {days}")
    w, left = float(weight_g), float(days)
    while left > 0:
        step = min(1.0, left)
        g = sgr_pct if sgr_pct is not None else table.sgr_pct(w, temp_c)
        if g is None:
            return None
        w *= math.exp(g / 100.0 * step)
        left -= step
    return w

