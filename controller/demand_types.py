"""The demand filter's events and its ``[demand]`` configuration (controller/demand.py)."""
from __future__ import annotations

from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["Demand", "DemandParams", "SensorFault", "SensorRecovered", "SlowFishUndetectable"]


@dataclass(frozen=True, slots=True)
class Demand:
    tank: str
    t: float
    rate_hz: float


@dataclass(frozen=True, slots=True)
class SensorFault:
    tank: str
    sensor: str
    t: float
    kind: str           # "stuck" | "dead"


@dataclass(frozen=True, slots=True)
class SlowFishUndetectable:
    """The tank's measured turbulence hides its slowest fish: raised once per tank."""
    tank: str
    t: float
    note: str


@dataclass(frozen=True, slots=True)
class SensorRecovered:
    tank: str
    sensor: str
    t: float


class DemandParams(BaseModel):
    """farm.toml ``[demand]``. Times in farm seconds."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    window_s: float = Field(60.0, ge=20, le=600, description="evidence window: the deadline")
    bin_s: float = Field(5.0, gt=0, le=30)
    slot_s: float = Field(1.0, gt=0, le=10, description="one contact per slot counts")
    chatter_hz: float = Field(3.0, gt=0, description="a bin faster than this is chatter")
    clump_contacts: int = Field(8, ge=3, description="short-burst test on a quiet tank, per 10 s")
    spike_gain: float = Field(3.0, ge=0)
    spike_allowance: float = Field(2.0, ge=0)
    false_alarms_per_day: float = Field(1.5, gt=0, lt=10, description="the count's nominal Poisson-tail budget")
    turbulence_max_hz: float = Field(0.05, gt=0, description="the contract's bound; starting estimate")
    turbulence_floor_hz: float = Field(0.005, gt=0)
    background_tau_s: float = Field(7200.0, gt=0)
    min_contacts: int = Field(4, ge=2, description="never demand on fewer occupied slots")
    end_fraction: float = Field(0.5, gt=0, le=1)
    repeat_s: float = Field(120.0, gt=0)
    repeat_contacts: int = Field(5, ge=1)
    stuck_rate_hz: float = Field(3.0, gt=0)
    stuck_window_s: float = Field(120.0, gt=0)
    stuck_share: float = Field(0.75, gt=0, le=1)
    recover_s: float = Field(60.0, gt=0)
    dead_after_s: float = Field(300.0, gt=0)
    dead_active_bins: int = Field(20, ge=1)
    dead_p: float = Field(1e-6, gt=0, lt=1, description="a live sensor this silent: less likely than this")
    run_cap: int = Field(1, ge=0, description="busy seconds a run of contacts (< 1 s apart) may count; 0: all")
    beat_false_alarms_per_day: float = Field(0.05, gt=0, lt=10)
    beat_jitter: tuple[float, ...] = Field((0.15, 0.35), min_length=1, max_length=4,
                                           description="beat tolerances, ± share of the period")
    beat_period_s: tuple[float, float] = (2.0, 12.0)
    beat_search_nodes: int = Field(30, ge=1)
    beat_window_s: float = Field(60.0, ge=20, le=1200, description="how far back a beat is looked for "
                                 "(180 s while a tank's turbulence is still the prior)")
    persist_window_s: float = Field(300.0, ge=0, le=1800,
                                    description="the persistence count's window (0: off)")
    persist_false_alarms_per_day: float = Field(0.1, gt=0, lt=10, description="its Poisson-tail budget")
    beat_single_s: float = Field(0.5, ge=0, description="closer contacts are a burst's, not a beat's")
    slow_fish_hz: float = Field(0.1, gt=0, description="the slowest fish the tank must serve")
    slow_fish_recall: float = Field(0.5, gt=0, lt=1, description="below this, say they are undetectable")
    learn_s: float = Field(3600.0, ge=0, description="measure this long before judging a tank")

    @model_validator(mode="after")
    def _shape(self):
        if self.window_s / self.bin_s < 6:
            raise ValueError("window_s must hold at least 6 bins of bin_s")
        if self.slot_s > self.bin_s:
            raise ValueError("slot_s must not exceed bin_s")
        if self.turbulence_floor_hz > self.turbulence_max_hz:
            raise ValueError("turbulence_floor_hz must not exceed turbulence_max_hz")
        if not all(0 < d <= 0.45 for d in self.beat_jitter):
            raise ValueError("beat_jitter values must lie in (0, 0.45]")
        if not 0 < self.beat_period_s[0] < self.beat_period_s[1]:
            raise ValueError("beat_period_s must be (shortest, longest) > 0")
        if self.beat_window_s < self.window_s:
            raise ValueError("beat_window_s must not be shorter than window_s")
        if self.persist_window_s and self.persist_window_s < 2 * self.window_s:
            raise ValueError("persist_window_s must be 0 (off) or at least twice window_s")
        return self
