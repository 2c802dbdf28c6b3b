"""Daily rations: biomass × feeding-table rate, and what is left of today's.

The stock is the config's count plus the stock events in the store (mortality, harvests,
transfers). The weights come from the tank's latest weight survey in the ledger, each fish fed by
its own weight class (controller/feeding/feeding_table.py) at the tank's water temperature, its
weights scaled to the mean weight the tank's growth fit (controller/growth.py: every survey of the
window pooled, ln W linear in time) gives for today — a survey is days old when the ration is
planned and one survey's mean is noisy (~4 % for 30 fish). With one survey in the window the chart's
expected growth projects it (not projected when the chart has none). A survey older than
``[feeding] survey_max_age_d`` is projected the same way and the ration says so (``projected``);
with no survey, the config's mean weight. A ration is fixed for a farm day when first asked for
(row in the store), so a restart or a config edit mid-day does not move the goalposts; a new survey
or a stock event plans it again, an operator's ration stands.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from controller.config import Config, load_toml, validate_section
from controller.errors import BadInput
from controller.feeding.feeding_table import (
    FeedingTable,
    load_feeding_table,
    project_weight,
    ration_from_weights,
    table_from_species,
)
from controller.growth import Z95, Weighing
from controller.ledger_writes import LedgerUnwritable
from controller.production import emptied_at, fitted_weight
from devices.clock import farm_date

DAY_S = 86_400.0
PLANNED = ("config", "survey", "projected")    # rations the controller plans (an operator's stands)
MIX_SAMPLE = 1000       # fish in the sample that mixes a tank's own with fish moved in (each in its share)


class FeedingRow(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    up_to_g: float = Field(gt=0)
    rate_pct: float = Field(gt=0, le=20)
    pellet_mm: float = Field(gt=0, le=50)


class Species(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str
    a: float = Field(gt=0, description="W = a * L^b, L fork length cm, W g")
    b: float = Field(gt=0)
    source: str | None = Field(None, description="where a, b come from")
    feeding: list[FeedingRow] = Field(min_length=1)
    survey: dict = Field({}, description="body shape for weight surveys: controller/surveys/species.py checks it")

    @model_validator(mode="after")
    def _rows_in_order(self):
        # a species without a chart is fed by these rows, looked up as a chart's classes are
        ups = [r.up_to_g for r in self.feeding]
        if any(b <= a for a, b in zip(ups, ups[1:], strict=False)):
            raise ValueError(f"feeding rows' up_to_g must increase strictly, not {ups}")
        return self

    def row(self, mean_weight_g: float) -> FeedingRow:
        for row in self.feeding:
            if mean_weight_g < row.up_to_g:
                return row
        return self.feeding[-1]


SOURCE_CONFIG = Path(__file__).resolve().parents[2] / "config"


def shipped_config(source: Path = SOURCE_CONFIG, prefixes: tuple[str, ...] = (sys.prefix, sys.base_prefix)) -> Path:
    """Where fishfarm's own species.toml and feeding charts are: the source tree's config/ (a
    checkout, an editable install), else the copy a wheel installs as data under
    ``<prefix>/share/fishfarm/config`` (pyproject.toml's data-files; a wheel once had none, and an
    installed fishfarm could neither run nor survey)."""
    if (source / "species.toml").is_file():
        return source
    for prefix in prefixes:
        installed = Path(prefix) / "share" / "fishfarm" / "config"
        if (installed / "species.toml").is_file():
            return installed
    return source                   # named in the error of whatever reads it


SHIPPED = shipped_config()
SPECIES_FILE = SHIPPED / "species.toml"


def species_file(config_path: str | Path | None = None) -> Path:
    """The species.toml a farm uses: one beside its farm.toml (a farm's own species), else fishfarm's."""
    if config_path is not None:
        beside = Path(config_path).parent / "species.toml"
        if beside.is_file():
            return beside
    return SPECIES_FILE


def load_species(path: str | Path = SPECIES_FILE) -> dict[str, Species]:
    raw = load_toml(path)
    return {key: validate_section(Species, value, str(path), key) for key, value in raw.items()}


@dataclass(frozen=True)
class Ration:
    tank: str
    date: str
    grams: float
    pellet_mm: float
    fed_g: float
    committed_g: float
    source: str = "config"          # config | survey | projected | operator

    @property
    def left_g(self) -> float:
        return max(0.0, self.grams - self.committed_g)


@dataclass(frozen=True)
class Plan:
    """What a planned ration rests on."""
    grams: float
    pellet_mm: float
    source: str                     # config | survey | projected
    mean_weight_g: float
    note: str
    growth: dict | None = None      # the growth fit today's weight comes from (GrowthFit.summary)


def ration_payload(r: Ration) -> dict:
    """``farm/{site}/tank/{tank}/ration``."""
    return {"date": r.date, "grams": round(r.grams, 1), "fed_g": round(r.fed_g, 1), "pellet_mm": r.pellet_mm,
            "basis": r.source}


class Rations:
    def __init__(self, cfg: Config, species: dict[str, Species], store):
        self.cfg = cfg
        self.store = store
        self.species = species
        self._stock: dict[str, int] = {}      # config + stock events, until the next event
        for tank in cfg.tanks:
            if tank.species not in species:
                raise ValueError(f"tank {tank.id}: unknown species {tank.species!r}")
        self.tables = load_tables(cfg, species)
        self.water = None                     # controller.water.WaterTemperatures, once devices are up
        self._plans: dict[tuple[str, str], Plan] = {}     # (tank, farm day) -> what today's plan rests on
        for key in {tank.species for tank in cfg.tanks} - self.tables.keys():
            self.tables[key] = table_from_species(key, species[key])

    def date(self, t: float) -> str:
        return farm_date(t, self.cfg.utc_offset_h)

    def stock(self, tank_id: str) -> int:
        """Fish in the tank: the config's stock plus the stock events recorded since."""
        if tank_id not in self._stock:
            self._stock[tank_id] = self.cfg.tank(tank_id).stock + self.store.stock_change(tank_id)
        return self._stock[tank_id]

    def restocked(self, tank_id: str, t: float) -> Ration:
        """A stock event was recorded: the count is read again, and today's ration planned again
        from it unless an operator set it (theirs stands)."""
        self._stock.pop(tank_id, None)
        return self.replan(tank_id, t)

    def replan(self, tank_id: str, t: float) -> Ration:
        """Plan today's ration again (a new survey, a new count), unless an operator set it."""
        current = self.today(tank_id, t)
        plan = self.plan(tank_id, t)
        self._plans[(tank_id, current.date)] = plan
        if current.source in PLANNED:
            # never below what the day has fed already: a survey recorded after the feeding set the
            # day's ration under it, and the ration in force when the fish were fed was lost
            grams = max(plan.grams, current.committed_g)
            self.store.set_ration(tank_id, current.date, grams, plan.pellet_mm, plan.source, t)
        return self.today(tank_id, t)

    def basis(self, tank_id: str, t: float) -> Plan:
        """What today's planned ration rests on (mean weight, survey or not), kept for the day."""
        key = (tank_id, self.date(t))
        if key not in self._plans:
            self._plans = {k: v for k, v in self._plans.items() if k[1] == key[1]}   # yesterday's go
            self._plans[key] = self.plan(tank_id, t)
        return self._plans[key]

    def water_temp_c(self, tank_id: str) -> float:
        """The thermometer's fresh reading for the tank, else the configured temperature."""
        if self.water is not None:
            return self.water.temperature(tank_id).celsius
        tank = self.cfg.tank(tank_id)
        return tank.water_temp_c if tank.water_temp_c is not None else self.cfg.feeding.water_temp_c

    def plan(self, tank_id: str, t: float) -> Plan:
        """Today's ration from the stock and the weights the ledger knows at ``t`` (module docstring)."""
        tank = self.cfg.tank(tank_id)
        table, temp, stock = self.tables[tank.species], self.water_temp_c(tank_id), self.stock(tank_id)
        newest = self.store.surveys(tank_id, until=t, limit=1)
        events = [dict(e) for e in self.store.stock_events()]
        emptied = emptied_at(tank.stock, events, tank_id, t)
        refilled = emptied is not None and (not newest or newest[0].t <= emptied)   # its surveyed fish gone
        weights, source, note, growth = self._weights(tank_id, t, table, temp, [] if refilled else newest,
                                                      events, emptied)
        weights, note = self._mixed_with_moved_in(tank_id, t, table, temp, weights, stock, note, events,
                                                  emptied if refilled else (newest[0].t if newest else -math.inf),
                                                  refilled)
        plan = ration_from_weights(weights, stock, temp, table)
        grams = plan.grams
        if tank.feeding_rate_pct is not None:          # the operator's rate for this tank, on its biomass
            grams = plan.biomass_g * tank.feeding_rate_pct / 100.0
        return Plan(grams, plan.pellet_mm, source, plan.mean_weight_g, note, growth)

    def _weights(self, tank_id: str, t: float, table: FeedingTable, temp: float, newest: list, events: list[dict],
                 emptied: float | None) -> tuple[np.ndarray, str, str, dict | None]:
        """The newest survey's fish (``newest``: none when the tank was emptied since), scaled to the
        growth fit's mean weight today (module docstring)."""
        if not newest and emptied is not None:
            first = next((e for e in sorted(events, key=lambda e: e["t"])
                          if e["t"] > emptied and e["to_tank"] == tank_id and e["t"] <= t), None)
            moved = None if first is None else self._moved_fish(first, t, table, temp)
            if moved is not None:
                weights, now, s = moved
                return (weights, "projected",
                        f"fish moved in from {first['tank']} on {self.date(first['t'])}: its survey of "
                        f"{self.date(s.t)} ({s.count} fish, mean {s.mean_weight_g:.1f} g) at the chart's growth: "
                        f"{now:.1f} g today", None)
        if not newest:
            w = self.cfg.tank(tank_id).mean_weight_g
            gone = "" if emptied is None else f" (the fish surveyed before {self.date(emptied)} are gone)"
            return np.array([w]), "config", f"no survey: the config's mean weight {w:g} g{gone}", None
        s = newest[0]
        weights = self.store.survey_weights(s.id)
        age_d = (t - s.t) / DAY_S
        source = "survey" if age_d <= self.cfg.feeding.survey_max_age_d else "projected"
        when = f"survey of {self.date(s.t)} ({s.count} fish, mean {s.mean_weight_g:.1f} g)"
        fitted = fitted_weight(self.cfg, self.store, tank_id, t, (table, temp))
        if isinstance(fitted, tuple):
            now, growth, how = fitted
        else:                           # one survey: the chart's growth, class by class as the fish grow
            now = project_weight(s.mean_weight_g, max(0.0, age_d), temp, table)
            why = "" if fitted is None else f" ({fitted})"
            if now is None:
                return weights, source, f"{when}, {age_d:.1f} days old; no growth known: not projected{why}", None
            one = Weighing(s.t, s.mean_weight_g, s.cv_pct, s.count)
            growth, how = {"model": "chart", "weight_g": now, "weight_ci_pct": 100 * math.expm1(Z95 * one.log_se),
                           "surveys": 1, "measured": False}, f"the feeding chart's growth{why}"
        return (weights * now / s.mean_weight_g, source,
                f"{when}, {age_d:.1f} days old: {now:.1f} g (±{growth['weight_ci_pct']:.1f} %) today at {how}",
                growth)

    def _mixed_with_moved_in(self, tank_id: str, t: float, table, temp: float, weights: np.ndarray, stock: int,
                             note: str, events: list[dict], since: float, refilled: bool) -> tuple[np.ndarray, str]:
        """``weights`` (the tank's own fish, as of ``since``: its newest survey, or the config's, or
        the first transfer into a tank emptied before — ``refilled``) mixed with the fish moved in
        after from tanks that surveyed them, each transfer's in its share of the stock
        (``_moved_fish``). 200 fish of 204 g moved into 2,400 of 24 g were fed as 24 g fish: the
        ration rested on 57.6 kg of a 93.6 kg tank. A survey after the transfer sees them all."""
        came = [e for e in sorted(events, key=lambda e: e["t"])
                if e["kind"] == "transfer" and e["to_tank"] == tank_id and since < e["t"] <= t]
        if refilled:
            came = came[1:]                        # the first refilled the tank: it is ``weights``
        groups = [(int(e["count"]), e, moved) for e in came
                  if (moved := self._moved_fish(e, t, table, temp)) is not None]   # unweighed: as the tank's own
        if not groups or stock <= 0:
            return weights, note
        own = max(stock - sum(n for n, _, _ in groups), 0)
        # one sample in which each group holds its share of the stock (cycled to length, in order)
        size = max(MIX_SAMPLE, len(weights), *(len(m[0]) for _, _, m in groups))
        parts = [np.resize(weights, round(size * own / stock))] if own else []
        parts += [np.resize(m[0], max(1, round(size * min(n, stock) / stock))) for n, _, m in groups]
        said = "; ".join(f"{n} fish moved in from {e['tank']} on {self.date(e['t'])} at {m[1]:.1f} g"
                         for n, e, m in groups)
        return np.concatenate(parts), f"{note}; {said}"

    def _moved_fish(self, e: dict, t: float, table, temp: float):
        """(weights g today, their mean today, the survey) of the fish transfer ``e`` moved: its
        source tank's newest survey before it, grown at the chart's rate to ``t``; None when the
        source was never surveyed."""
        source = self.store.surveys(e["tank"], until=e["t"], limit=1)
        if not source:
            return None
        s = source[0]
        now = project_weight(s.mean_weight_g, max(0.0, (t - s.t) / DAY_S), temp, table) or s.mean_weight_g
        return self.store.survey_weights(s.id) * now / s.mean_weight_g, now, s

    def today(self, tank_id: str, t: float) -> Ration:
        date = self.date(t)
        row = self.store.ration(tank_id, date)
        if row is None:
            plan = self._plans.get((tank_id, date)) or self.plan(tank_id, t)
            self._plans[(tank_id, date)] = plan
            try:
                self.store.set_ration(tank_id, date, plan.grams, plan.pellet_mm, plan.source, t)
            except LedgerUnwritable:
                # the day's plan stands in memory, and is written once the ledger can take it:
                # status, SCADA and the ration topic go on showing it (nothing is fed meanwhile)
                row = {"grams": plan.grams, "pellet_mm": plan.pellet_mm, "source": plan.source}
            else:
                row = self.store.ration(tank_id, date)
        return Ration(tank_id, date, row["grams"], row["pellet_mm"],
                      self.store.fed_g(tank_id, date), self.store.committed_g(tank_id, date), row["source"])

    def payload(self, tank_id: str, t: float) -> dict:
        """``farm/{site}/tank/{tank}/ration``; a planned ration adds (optional fields) the mean weight
        it rests on and that weight's 95 % half-width, % (``weight_ci_pct``, with a survey)."""
        r = self.today(tank_id, t)
        out = ration_payload(r)
        if r.source in PLANNED:
            basis = self.basis(tank_id, t)
            out["mean_weight_g"] = round(basis.mean_weight_g, 2)
            if basis.growth is not None:
                out["weight_ci_pct"] = round(basis.growth["weight_ci_pct"], 2)
        return out

    def set(self, tank_id: str, t: float, grams: float, source: str) -> Ration:
        current = self.today(tank_id, t)
        self.store.set_ration(tank_id, current.date, grams, current.pellet_mm, source, t)
        return self.today(tank_id, t)

    def portion(self, tank_id: str, t: float, overshoot: float) -> float:
        """Grams to aim for now: the configured portion, shrunk so that even an auger run
        that delivers ``overshoot`` (fraction) more than aimed keeps the tank within its ration."""
        ration = self.today(tank_id, t)
        grams = min(self.cfg.feeding.portion_g, ration.left_g / (1.0 + overshoot))
        return grams if grams >= self.cfg.feeding.min_portion_g else 0.0


def load_tables(cfg: Config, species: dict | None = None) -> dict[str, FeedingTable]:
    """``[feeding] tables``: one chart per species. A relative path is looked for beside farm.toml,
    then among the charts shipped with fishfarm (its config/ directory, as species.toml). With
    ``species`` (species.toml's), a chart for a species not there is refused: a typo would leave
    the chart unused and the tanks fed by the species' rows instead."""
    base = Path(cfg.path).parent if Path(cfg.path).is_file() else Path.cwd()
    tables: dict[str, FeedingTable] = {}
    for i, name in enumerate(cfg.feeding.tables):
        path = Path(name)
        if not path.is_absolute():
            path = base / name if (base / name).is_file() or not (SHIPPED / name).is_file() else SHIPPED / name
        if not path.is_file():
            why = ("a directory, not a chart" if path.is_dir() else "not a regular file" if path.exists()
                   else "no such file")         # /tmp and /dev/null were "no such file"
            raise BadInput(cfg.path, f"feeding.tables.{i}", f"{path}: {why}")
        table = load_feeding_table(path)
        if species is not None and table.species not in species:
            raise BadInput(cfg.path, f"feeding.tables.{i}", f"{path.name} is a chart for {table.species!r}, a "
                                                             f"species species.toml does not know (known: "
                                                             f"{', '.join(sorted(species))})")
        if table.species in tables:
            raise BadInput(cfg.path, f"feeding.tables.{i}", f"a second table for {table.species!r}")
        tables[table.species] = table
    return tables
