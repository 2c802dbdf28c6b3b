"""Demand filter benchmark: what it catches on the independent contract streams, and its speed.

Run: ``.venv/bin/python bench/bench_demand.py [--case-days 12] [--contract-null-days 120]
[--seeds 2] [--contract-only]``; prints one JSON object (``--seeds 21 22``: the held-out seeds,
never tuned on, pooled):
- ``cases``: per named hard case of tests/contract_streams.py (written from DESIGN.md's contact
  model, independently of the filter and of devices/sim/contact_streams.py): recall within 60 s
  of each episode's first contact, latency p50/p95, false demands per tank-day, faults found, and
  ``bound``: the ideal detector's recall (contract.oracle_recall) on the same stream;
- ``null``: false demands per tank-day over ``--null-days`` of background, bursts and waves;
- ``filter``: contacts/s through ``DemandFilter.on_contact`` on one core (goal >= 200,000), on
  the simulator's farm stream (8 tanks x 2 sensors, fish 0.1-2 /s, turbulence 0.05 /s, bursts
  4 /h); ``cli_replay``: the same through ``fishfarm demand`` on a CSV.

``--table [--episodes 200]`` measures instead what the filter catches (the table of
controller/demand.py): per fish pattern x turbulence x rate, the share of 2-minute episodes
with a demand within 60 s of their start (turbulence and chatter bursts 4 /h all along, a tank
with two sensors), and demands outside any episode. ``--null-days N`` counts false demands
over N tank-days of turbulence and chatter bursts (6 /h) alone, at 0.01, 0.02 and 0.05 /s.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from controller.demand import Demand, DemandFilter, SensorFault
from devices.sim import contact_streams as cs

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests import contract_streams as contract  # noqa: E402  (the independent generator)


def run_contract(farm) -> contract.Score:
    f, ds, faults, nxt = DemandFilter(), [], [], -math.inf
    for t, tank, sensor in farm.rows():
        events = f.on_time(t) if t >= nxt else ()
        if t >= nxt:
            nxt = t + 5.0
        for e in (*events, *f.on_contact(t, tank, sensor)):
            if isinstance(e, Demand):
                ds.append((e.tank, e.t))
            elif isinstance(e, SensorFault):
                faults.append((e.tank, e.sensor, e.kind, e.t))
    return contract.score(farm, ds, faults)


def contract_cases(days: float, null_days: float, seeds: tuple[int, ...] = (2,)) -> dict:
    """Every named case on each seed, pooled: episodes, demands and faults summed over seeds."""
    cases = {}
    for name in (*contract.CASES, "every"):
        scores, bound = [], 0.0
        for seed in seeds:
            farm = contract.case(name, seed=seed, days=days)
            scores.append(run_contract(farm))
            bound += contract.oracle_recall(farm) * len(farm.episodes)
        s = _pool(scores)
        cases[name] = {**s.as_dict(), "bound": round(bound / max(1, s.episodes), 4)}
    null = _pool([run_contract(contract.null_days(seed, null_days)) for seed in seeds]).as_dict()
    return {"seeds": list(seeds), "case_tank_days": days * len(seeds), "cases": cases,
            "null": {"tank_days": null_days * len(seeds), "false_demands": null["false_demands"],
                     "false_per_tank_day": null["false_per_tank_day"], "wrong_faults": null["wrong_faults"]}}


def _pool(scores: list[contract.Score]) -> contract.Score:
    def total(name):
        return sum(getattr(s, name) for s in scores)
    return contract.Score(total("episodes"), total("caught_60s"), [x for s in scores for x in s.latencies],
                          total("false_demands"), total("afterglow"), total("tank_days"), total("faults"),
                          total("faults_found"), total("wrong_faults"), [e for s in scores for e in s.missed])


def farm_stream(days: float, seed: int = 1) -> cs.Stream:
    rng = np.random.default_rng(seed)
    return cs.merge(*[cs.tank_day(rng, f"T{i}", (f"T{i}-a", f"T{i}-b"), 1.78e9, days, episodes_per_day=12,
                                  turbulence_hz=0.05, bursts_per_hour=4) for i in range(1, 9)])


def filter_rate(stream: cs.Stream, repeats: int = 3) -> dict:
    ts, tanks, sensors = stream.t.tolist(), stream.tank.tolist(), stream.sensor.tolist()
    best = 0.0
    for _ in range(repeats):
        f = DemandFilter()
        oc = f.on_contact
        t0 = time.perf_counter()
        for t, k, s in zip(ts, tanks, sensors, strict=True):
            oc(t, k, s)
        best = max(best, len(ts) / (time.perf_counter() - t0))
    return {"contacts": len(ts), "contacts_per_s": round(best)}


def cli_rate(days: float) -> dict:
    stream = farm_stream(days, seed=2)
    with tempfile.TemporaryDirectory() as d:
        csv, out = Path(d) / "contacts.csv", Path(d) / "out.json"
        stream.write_csv(csv)
        exe = str(Path(sys.executable).parent / "fishfarm")
        cmd = [exe, "demand", "--events", str(csv), "--json", str(out)]
        cmd = ["taskset", "-c", "0", *cmd] if _has_taskset() else cmd
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, cwd=ROOT)
        wall = time.perf_counter() - t0
        demands = len(json.loads(out.read_text())["demands"])
        size_mb = round(os.path.getsize(csv) / 1e6, 1)
    return {"rows": len(stream), "csv_mb": size_mb, "wall_s": round(wall, 2),
            "rows_per_s": round(len(stream) / wall), "demands": demands}


def _has_taskset() -> bool:
    from shutil import which
    return which("taskset") is not None


PATTERNS = {"poisson": ("poisson", 0.0), "regular j=0.1": ("regular", 0.1), "regular j=0.3": ("regular", 0.3),
            "paced j=0.3": ("paced", 0.3)}
RATES = (0.1, 0.15, 0.2, 0.25, 0.3, 0.45)


def replay_demands(stream: cs.Stream) -> list[float]:
    """Demand times, the filter fed as the controller feeds it (on_time every 5 s)."""
    f, out, nxt = DemandFilter(), [], -math.inf
    for t, tank, sensor in stream.rows():
        if t >= nxt:
            f.on_time(t)
            nxt = t + 5.0
        out += [e.t for e in f.on_contact(t, tank, sensor) if isinstance(e, Demand)]
    return out


def episode_cell(rate: float, turbulence_hz: float, pattern: str, jitter: float, episodes: int,
                 seed: int) -> tuple[float, int]:
    """(share of episodes with a demand within 60 s of the start, demands outside episodes)."""
    rng = np.random.default_rng(seed)
    t0 = 1.78e9                                     # an hour to learn the tank's turbulence first
    starts = t0 + 3600 + np.cumsum(1200 + rng.exponential(300, episodes))
    t1 = float(starts[-1]) + 1200
    parts = [cs.turbulence(rng, "T1", ("a", "b"), t0, t1, turbulence_hz),
             cs.chatter_bursts(rng, "T1", ("a", "b"), t0, t1, 4.0)]
    parts += [cs.fish_demand(rng, "T1", ("a", "b"), a, 120.0, rate, pattern, jitter) for a in starts.tolist()]
    stream = cs.merge(*parts)
    ds = replay_demands(stream)
    eps = stream.episodes
    served = sum(any(e.start <= d <= e.start + 60 for d in ds) for e in eps)
    return served / len(eps), sum(not any(e.start <= d <= e.end for e in eps) for d in ds)


def detection_table(episodes: int) -> dict:
    rows = {}
    for name, (pattern, jitter) in PATTERNS.items():
        for b in (0.01, 0.02, 0.05):
            cells = [episode_cell(r, b, pattern, jitter, episodes, seed=int(r * 1000 + b * 1e4))
                     for r in RATES]
            rows[f"{name} b={b}"] = {"within_60s": [round(c[0], 2) for c in cells],
                                      "outside": sum(c[1] for c in cells)}
    return {"rates_hz": RATES, "episodes_per_cell": episodes, "rows": rows}


def null_days(days: int) -> dict:
    out = {}
    for b in (0.01, 0.02, 0.05):
        rng = np.random.default_rng(int(b * 1000))
        false = 0
        for d0 in range(0, days, 20):
            stream = cs.merge(*[cs.tank_day(rng, "T1", ("a", "b"), 1.78e9 + d * 86400, episodes_per_day=1e-9,
                                            turbulence_hz=b, bursts_per_hour=6) for d in range(d0, min(days, d0 + 20))])
            false += len(replay_demands(stream))
        out[f"b={b}"] = false
    return {"tank_days_each": days, "false_demands": out}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--days", type=float, default=2.0)
    ap.add_argument("--csv-days", type=float, default=2.0)
    ap.add_argument("--table", action="store_true", help="the detection table instead of the speed")
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--null-days", type=int, default=0, help="with --table: the simulator's null streams")
    ap.add_argument("--case-days", type=float, default=12.0)
    ap.add_argument("--contract-null-days", type=float, default=120.0)
    ap.add_argument("--speed-only", action="store_true")
    ap.add_argument("--seeds", type=int, nargs="+", default=[2],
                    help="contract seeds, pooled (2: the bench's own; 21 22: held out, never tuned on)")
    ap.add_argument("--contract-only", action="store_true", help="skip the speed figures")
    args = ap.parse_args()
    if args.table or args.null_days:
        report = {}
        if args.table:
            report["detection"] = detection_table(args.episodes)
        if args.null_days:
            report["null"] = null_days(args.null_days)
        print(json.dumps(report))
        return
    if args.contract_only:
        print(json.dumps({"contract": contract_cases(args.case_days, args.contract_null_days, tuple(args.seeds))}))
        return
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})       # one core
    report = {"filter": filter_rate(farm_stream(args.days)), "goal_contacts_per_s": 200_000,
              "cli_replay": cli_rate(args.csv_days)}
    report["goal_met"] = report["filter"]["contacts_per_s"] >= 200_000
    if not args.speed_only:
        report["contract"] = contract_cases(args.case_days, args.contract_null_days, tuple(args.seeds))
    print(json.dumps(report))


if __name__ == "__main__":
    main()
