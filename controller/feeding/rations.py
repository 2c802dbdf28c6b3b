"""Daily rations: biomass × feeding-table rate, and what is left of today's.

Until a weight survey exists for a tank, biomass is its stock × the config's mean weight, the stock
being the config's count plus the stock events in the store (mortality, harvests, transfers). A
ration is fixed for a farm day when first asked for (row in the store), so a restart or a
config edit mid-day does not move the goalposts; an operator or a survey may replace it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from controller.config import Config, load_toml, validate_section
from devices.clock import farm_date


class FeedingRow(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    up_to_g: float = Field(gt=0)
    rate_pct: float = Field(gt=0, le=20)
    pellet_mm: float = Field(gt=0)


class Species(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str
    a: float = Field(gt=0, description="W = a * L^b, L fork length cm, W g")
    b: float = Field(gt=0)
    source: str | None = Field(None, description="where a, b come from")
    feeding: list[FeedingRow] = Field(min_length=1)
    survey: dict = Field({}, description="body shape for weight surveys: controller/surveys/species.py checks it")

    def row(self, mean_weight_g: float) -> FeedingRow:
        for row in self.feeding:
            if mean_weight_g < row.up_to_g:
                return row
        return self.feeding[-1]


SPECIES_FILE = Path(__file__).resolve().parents[2] / "config" / "species.toml"


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

    @property
    def left_g(self) -> float:
        return max(0.0, self.grams - self.committed_g)


def ration_payload(r: Ration) -> dict:
    """``farm/{site}/tank/{tank}/ration``."""
    return {"date": r.date, "grams": round(r.grams, 1), "fed_g": round(r.fed_g, 1), "pellet_mm": r.pellet_mm}


class Rations:
    def __init__(self, cfg: Config, species: dict[str, Species], store):
        self.cfg = cfg
        self.store = store
        self.species = species
        self._stock: dict[str, int] = {}      # config + stock events, until the next event
        for tank in cfg.tanks:
            if tank.species not in species:
                raise ValueError(f"tank {tank.id}: unknown species {tank.species!r}")

    def date(self, t: float) -> str:
        return farm_date(t, self.cfg.utc_offset_h)

    def stock(self, tank_id: str) -> int:
        """Fish in the tank: the config's stock plus the stock events recorded since."""
        if tank_id not in self._stock:
            self._stock[tank_id] = self.cfg.tank(tank_id).stock + self.store.stock_change(tank_id)
        return self._stock[tank_id]

    def restocked(self, tank_id: str, t: float) -> Ration:
        """A stock event was recorded: the count is read again, and today's ration planned again
        from it unless an operator or a survey set it (theirs stands)."""
        self._stock.pop(tank_id, None)
        current = self.today(tank_id, t)
        row = self.store.ration(tank_id, current.date)
        if row is not None and row["source"] == "config":
            grams, pellet = self.planned(tank_id)
            self.store.set_ration(tank_id, current.date, grams, pellet, "config", t)
        return self.today(tank_id, t)

    def planned(self, tank_id: str) -> tuple[float, float]:
        """(grams a day, pellet mm) from the stock, the config's mean weight and the species table."""
        tank = self.cfg.tank(tank_id)
        row = self.species[tank.species].row(tank.mean_weight_g)
        rate = tank.feeding_rate_pct if tank.feeding_rate_pct is not None else row.rate_pct
        return self.stock(tank_id) * tank.mean_weight_g * rate / 100.0, row.pellet_mm

    def today(self, tank_id: str, t: float) -> Ration:
        date = self.date(t)
        row = self.store.ration(tank_id, date)
        if row is None:
            grams, pellet = self.planned(tank_id)
            self.store.set_ration(tank_id, date, grams, pellet, "config", t)
            row = self.store.ration(tank_id, date)
        return Ration(tank_id, date, row["grams"], row["pellet_mm"],
                      self.store.fed_g(tank_id, date), self.store.committed_g(tank_id, date))

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
