"""Rations, FCR and SGR from noisy surveys, judged against the fish they were taken of — in one
process, in seconds: issue 10's accuracy goals (rations within 5 % of the true biomass, FCR and SGR
within 5 % of the simulated ones) without rendering a frame.

A tank (the demo's T1: 2400 sea bream of 18 g at 22 °C) is the simulator's own stock
(devices/sim/stock.py: fish that grow on the food they eat, biological FCR 1.4, 0.05 % deaths a
day). Each farm day the controller's own ration code (controller/feeding/rations.py, a ledger in
memory) plans the ration at 06:00, the fish eat it in 8 meals by 20:00, the day's deaths are entered
as `mortality`; every 7th day at 20:30 a survey is drawn as the stereo survey measures: ``FISH``
fish picked at random, a fish's chance of being found growing with its length as L^gamma
(``DETECT_GAMMA``: 4.4 makes the fish found ~2 % longer than the stock's at a 20 % weight CV — README
"Nursery-sized fish read heavy"), every length read ``LENGTH_BIAS_PCT`` long (+0.8 %) and the weight
from the length with the condition-factor scatter of one fish (``CONDITION_SD``, log sd).

Per configuration (fish a survey × the fit's window and model × biased or not), over ``SEEDS`` seeds, for
runs of 14 and 60 days:
- ``ration``: the biomass the ration rests on (the controller's stock × its mean weight) and the
  ration itself against the ones the true fish call for (same chart), every day from the first
  survey on: bias, RMS, 95th percentile of |error| and the share of days within 5 %;
- ``sgr`` / ``fcr``: at the run's last survey, the fitted figures (controller/production.py:
  fitted_figures) against the simulator's over the same window, their share within 5 %, and how
  often the stated 95 % interval held the truth; ``*_consecutive``: the same for the figures between
  the last two surveys (what `fishfarm report` showed before).

Run: ``.venv/bin/python bench/bench_rations.py``; BENCH_RATIONS_SEEDS (default 40),
BENCH_RATIONS_FISH (default "30,62,120"), BENCH_RATIONS_WINDOWS (days, default "28,56"),
BENCH_RATIONS_MODELS (``[feeding] growth_model``s, default "feed,sgr").
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from controller.config import load_config  # noqa: E402
from controller.feeding.feeding_table import ration_from_weights  # noqa: E402
from controller.feeding.rations import Rations, load_species  # noqa: E402
from controller.production import SurveyPoint, fitted_figures, interval  # noqa: E402
from controller.store import Store  # noqa: E402
from devices.sim.stock import SimStock, SimStockParams  # noqa: E402

SEEDS = int(os.environ.get("BENCH_RATIONS_SEEDS", "40"))
FISH = [int(x) for x in os.environ.get("BENCH_RATIONS_FISH", "30,62,120").split(",")]
WINDOWS = [float(x) for x in os.environ.get("BENCH_RATIONS_WINDOWS", "28,56").split(",")]
MODELS = os.environ.get("BENCH_RATIONS_MODELS", "feed,sgr").split(",")
RUN_DAYS = (14, 60)
DETECT_GAMMA = 4.4
LENGTH_BIAS_PCT = 0.8
CONDITION_SD = 0.08
TANK = "T1"
DAY = 86_400.0
T0 = 1_780_012_800.0 - 3600.0          # 2026-05-29 00:00 local (utc_offset_h 1)
MEALS = 8


class Survey:
    """How the stereo survey sees a stock (module docstring)."""

    def __init__(self, a: float, b: float, fish: int, biased: bool):
        self.a, self.b, self.fish, self.biased = a, b, fish, biased

    def draw(self, stock: SimStock, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        w = stock.w
        p = (w ** (DETECT_GAMMA / self.b)) if self.biased else np.ones_like(w)   # L^gamma, L ∝ W^(1/b)
        picked = w[rng.choice(len(w), self.fish, p=p / p.sum())]
        length = (picked / self.a) ** (1 / self.b) * (1 + LENGTH_BIAS_PCT / 100 if self.biased else 1.0)
        length *= np.exp(rng.normal(-CONDITION_SD**2 / 2, CONDITION_SD, self.fish) / self.b)   # its own condition
        return length, self.a * length ** self.b


def run(seed: int, days: int, fish: int, window_d: float, model: str, biased: bool, cfg, species) -> dict:
    cfg = cfg.model_copy(update={"feeding": cfg.feeding.model_copy(update={"growth_window_d": window_d,
                                                                           "growth_model": model})})
    store = Store(":memory:")
    rations = Rations(cfg, species, store)
    tank = cfg.tank(TANK)
    rng = np.random.default_rng(seed)
    stock = SimStock(TANK, tank.stock, tank.mean_weight_g, SimStockParams(), np.random.default_rng(seed + 10**6),
                     T0)
    sp = species[tank.species]
    survey = Survey(sp.a, sp.b, fish, biased)
    table, temp = rations.tables[tank.species], rations.water_temp_c(TANK)
    biomass_err, ration_err, truth = [], [], []          # truth: (t, mean g, biomass g, feed g, dead g) at surveys
    fed = dead_g = 0.0
    entered = 0                                          # deaths entered as mortality so far
    for d in range(days + 1):
        day = T0 + d * DAY
        t = day + 6 * 3600
        stock.advance(t)
        if store.surveys(TANK, limit=1):
            plan = rations.basis(TANK, t)
            ideal = ration_from_weights(stock.w, stock.count, temp, table).grams
            biomass_err.append(rations.stock(TANK) * plan.mean_weight_g / stock.biomass_g - 1)
            ration_err.append(rations.today(TANK, t).grams / ideal - 1)
        grams = rations.today(TANK, t).grams
        for k in range(MEALS):
            stock.feed(grams / MEALS, t + k * 2 * 3600)
        f = store.add_intent(tank=TANK, date=rations.date(t), t=t, target_g=grams, run_s=1, cycles_before=0,
                             source="bench")
        store.close_feed(f.id, "done", grams, t)
        fed += grams
        if d % 7 == 0:
            ts = day + 20.5 * 3600
            stock.advance(ts)
            length, weight = survey.draw(stock, rng)
            store.add_survey(TANK, ts, tank.species, "bench", length, weight)
            truth.append((ts, stock.mean_g, stock.biomass_g, fed, dead_g))
        stock.advance(day + DAY - 1)
        if stock.deaths > entered:             # the day's dead, counted at its end as a farm worker would
            dead_g += (stock.deaths - entered) * stock.mean_g
            store.add_stock_event(t=day + DAY - 1, tank=TANK, kind="mortality", count=stock.deaths - entered,
                                  to_tank=None, who="bench")
            entered = stock.deaths
            rations.restocked(TANK, day + DAY - 1)
    out = {"biomass": biomass_err, "ration": ration_err}
    out |= judge_fit(fitted_figures(cfg, store, TANK, truth[-1][0]), truth)
    out |= judge_consecutive(cfg, store, truth)
    return out


def true_between(truth, t1: float, t2: float) -> tuple[float, float]:
    """The simulator's SGR (% a day) and FCR (food / (biomass gain + the dead's weight)) over [t1, t2]."""
    a = next(x for x in truth if x[0] == t1)
    b = next(x for x in truth if x[0] == t2)
    sgr = 100 * math.log(b[1] / a[1]) / ((t2 - t1) / DAY)
    return sgr, (b[3] - a[3]) / (b[2] - a[2] + b[4] - a[4])


def judge_fit(fig: dict | None, truth) -> dict:
    if fig is None:
        return {}
    sgr, fcr = true_between(truth, fig["t_first"], fig["t_last"])
    lo, hi = fig["fcr_ci"]
    half = fig["sgr_ci_pct_day"]
    return {"sgr": fig["sgr_pct_day"] / sgr - 1, "sgr_covered": abs(fig["sgr_pct_day"] - sgr) <= half,
            "sgr_ci_rel": half / sgr,
            "fcr": (fig["fcr"] / fcr - 1) if fig["fcr"] else math.inf,
            "fcr_covered": (lo is None or lo <= fcr) and (hi is None or fcr <= hi)}


def judge_consecutive(cfg, store, truth) -> dict:
    """The figures between the last two surveys, as production.interval reports them."""
    rows = sorted(store.surveys(TANK, limit=2), key=lambda s: s.t)
    if len(rows) < 2:
        return {}
    events = [dict(e) for e in store.stock_events()]
    base = cfg.tank(TANK).stock
    from controller.production import stock_at
    p = [SurveyPoint(s.t, s.mean_weight_g, s.cv_pct, 0.0, s.count, stock_at(base, events, TANK, s.t)) for s in rows]
    iv = interval(p[0], p[1], store.fed_between(TANK, p[0].t, p[1].t), events, TANK)
    sgr, fcr = true_between(truth, p[0].t, p[1].t)
    return {"sgr_consecutive": iv.sgr_pct / sgr - 1, "fcr_consecutive": (iv.fcr / fcr - 1) if iv.fcr else math.inf}


def stats(errors: list[float]) -> dict:
    e = np.asarray(errors, float)
    fin = e[np.isfinite(e)]
    return {"bias_pct": round(100 * float(fin.mean()), 2), "rms_pct": round(100 * float(np.sqrt(np.mean(fin**2))), 2),
            "p95_abs_pct": round(100 * float(np.quantile(np.abs(e), 0.95)), 2) if len(fin) == len(e) else None,
            "within_5pct": round(float(np.mean(np.abs(e) <= 0.05)), 3), "n": int(len(e))}


def configuration(days: int, fish: int, window_d: float, model: str, biased: bool, cfg, species) -> dict:
    runs = [run(seed, days, fish, window_d, model, biased, cfg, species) for seed in range(SEEDS)]
    out = {"days": days, "fish": fish, "window_d": window_d, "model": model, "biased": biased,
           "biomass": stats([e for r in runs for e in r["biomass"]]),
           "ration": stats([e for r in runs for e in r["ration"]])}
    for key in ("sgr", "fcr", "sgr_consecutive", "fcr_consecutive"):
        if key in runs[0]:
            out[key] = stats([r[key] for r in runs])
    for key in ("sgr_covered", "fcr_covered"):
        if key in runs[0]:
            out[key.replace("_covered", "")]["ci95_held"] = round(float(np.mean([r[key] for r in runs])), 3)
    if "sgr_ci_rel" in runs[0]:
        out["sgr"]["ci95_half_median_pct"] = round(100 * float(np.median([r["sgr_ci_rel"] for r in runs])), 1)
    return out


def main() -> None:
    cfg = load_config(ROOT / "config" / "farm.toml")
    species = load_species()
    started = time.process_time()
    results = [configuration(days, fish, window, model, biased, cfg, species)
               for biased in (False, True) for days in RUN_DAYS for fish in FISH for window in WINDOWS
               for model in MODELS]
    print(json.dumps({"seeds": SEEDS, "cpu_s": round(time.process_time() - started, 1),
                      "detect_gamma": DETECT_GAMMA, "length_bias_pct": LENGTH_BIAS_PCT, "results": results},
                     indent=1))


if __name__ == "__main__":
    from bench import no_arguments

    no_arguments(__doc__)
    main()
