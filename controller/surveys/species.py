"""A species' survey settings from config/species.toml, and a stock's own a, b from farm.toml.

species.toml is shared with the feeding controller (controller/feeding/rations.py reads the
same file); the survey reads its ``[NAME.survey]`` sub-table, checked here (Klipper's rule: the
component that uses a section validates it). farm.toml ``[stocks.NAME]`` overrides a, b for one
stock of fish: fitted on that stock's hand-weighed sample, better than the species' typical figure.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, model_validator

from controller.config import load_toml, validate_section
from controller.errors import BadInput
from controller.feeding.rations import SPECIES_FILE, load_species
from vision.survey_types import FishGeometry, LengthWeight, SurveySetup


class SurveyShape(BaseModel):
    """``[NAME.survey]``: what FishGeometry reads, and optional illumination references."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    min_length_cm: float = Field(FishGeometry.min_length_cm, gt=0, le=500)
    max_length_cm: float = Field(FishGeometry.max_length_cm, gt=0, le=500)
    max_tilt_deg: float = Field(FishGeometry.max_tilt_deg, gt=0, le=90)
    depth_to_length: float = Field(FishGeometry.depth_to_length, gt=0, lt=1)
    fin_base_to_fork: float | None = Field(None, gt=0.5, lt=1.0,
                                           description="standard length / fork length (surface setup)")
    mi_ref: float = Field(SurveySetup.mi_ref, gt=0, lt=255, description="eq. 11 reference mean intensity")
    c_ref: float = Field(SurveySetup.c_ref, gt=0, lt=255, description="eq. 12 reference contrast")

    @model_validator(mode="after")
    def _range(self):
        if self.min_length_cm >= self.max_length_cm:
            raise ValueError(f"min_length_cm ({self.min_length_cm:g}) must be below max_length_cm "
                             f"({self.max_length_cm:g})")
        return self

    def geometry(self) -> FishGeometry:
        return FishGeometry(self.min_length_cm, self.max_length_cm, self.max_tilt_deg, self.depth_to_length,
                            self.fin_base_to_fork)


STOCK_SPAN = 3.0         # a stock's weight at a length within this factor of its species' law


class StockSection(BaseModel):
    """farm.toml ``[stocks.NAME]``: one stock's length-weight coefficients."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    species: str
    a: float = Field(gt=0, lt=1, description="W = a * L^b, L fork length cm, W g")
    b: float = Field(ge=2, le=4, description="2.5-3.5 for nearly every fish (Froese 2006)")
    source: str = Field("farm.toml", description="how a, b were fitted")


@dataclass(frozen=True)
class SurveySpecies:
    key: str                    # "sparus_aurata"
    name: str                   # "gilthead sea bream"
    weight: LengthWeight
    source: str                 # where a, b come from
    shape: SurveyShape

    def setup(self, setup: str, up_world: tuple[float, float, float] | None,
              floor_mm: float | None = None) -> SurveySetup:
        return SurveySetup(setup=setup, mi_ref=self.shape.mi_ref, c_ref=self.shape.c_ref,
                           geometry=self.shape.geometry(), up_world=up_world, floor_mm=floor_mm)

    def coefficients(self) -> dict:
        """The optional OUT.json field saying which a, b made the weights."""
        return {"a": self.weight.a, "b": self.weight.b, "source": self.source}


def survey_species(key: str, path: str | Path = SPECIES_FILE) -> SurveySpecies:
    """The species ``key`` (``--species``); BadInput listing the known ones if it is not there."""
    species = load_species(path)
    if key not in species:
        raise BadInput("--species", None, f"unknown species {key!r} (known: {', '.join(sorted(species))})")
    sp = species[key]
    shape = validate_section(SurveyShape, sp.survey, str(path), f"{key}.survey")
    return SurveySpecies(key, sp.name, LengthWeight(sp.a, sp.b), sp.source or str(path), shape)


def with_stock(species: SurveySpecies, config_path: str | Path, stock: str) -> SurveySpecies:
    """``species`` with a, b of farm.toml ``[stocks.<stock>]``; BadInput naming file and key."""
    where = str(config_path)
    stocks = load_toml(config_path).get("stocks", {})
    if not isinstance(stocks, dict) or stock not in stocks:
        known = ", ".join(sorted(stocks)) if isinstance(stocks, dict) and stocks else "none"
        raise BadInput(where, f"stocks.{stock}", f"no such stock (stocks: {known})")
    section = validate_section(StockSection, stocks[stock], where, f"stocks.{stock}")
    if section.species != species.key:
        raise BadInput(where, f"stocks.{stock}.species",
                       f"{section.species!r}, but the survey is of {species.key!r} (--species)")
    own = stock_law(species, section, where, stock)
    return SurveySpecies(species.key, species.name, own, f"farm.toml stocks.{stock}: {section.source}",
                         species.shape)


def stock_law(species: SurveySpecies, section: StockSection, where: str, stock: str) -> LengthWeight:
    """The length-weight law of farm.toml ``[stocks.<stock>]`` (its species ``species``), refused
    naming ``stocks.<stock>.a`` where its fish would weigh what no fish of the species might."""
    own = LengthWeight(section.a, section.b)
    # a and b are each within their bounds in nonsense pairs (a = 1e-30 gave every fish 0.0 g; a in
    # kg is 1000 x light): the stock's fish must weigh what fish of their species might, within a
    # factor of STOCK_SPAN of the species' law at a middling length (the paper's nursery stock:
    # a = 0.012 against the species' 0.02263, 0.53 x)
    mid = math.sqrt(species.shape.min_length_cm * species.shape.max_length_cm)
    w, typical = float(own.weight_g(mid)), float(species.weight.weight_g(mid))
    if not 1 / STOCK_SPAN <= w / typical <= STOCK_SPAN:
        raise BadInput(where, f"stocks.{stock}.a", f"a = {section.a:g}, b = {section.b:g} weigh a {mid:.0f} cm fish "
                                                   f"{w:.3g} g, {w / typical:.2g} x the {typical:.3g} g of "
                                                   f"{species.key}'s own law: a unit slip?")
    return own
