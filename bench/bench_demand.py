"""Demand filter benchmark: contacts/s through ``DemandFilter.on_contact`` on one core, and the
offline replay of a large generated CSV through ``fishfarm demand`` (the same filter).

Run: ``.venv/bin/python bench/bench_demand.py [--days 30] [--csv-days 30]``; prints one JSON
object. The stream is 8 tanks x 2 sensors: fish episodes (0.1-2 /s), turbulence at 0.05 /s,
chatter bursts 4 /h. Goal: >= 200,000 contacts/s through on_contact.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from controller.demand import DemandFilter
from devices.sim import contact_streams as cs

ROOT = Path(__file__).resolve().parents[1]


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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--days", type=float, default=2.0)
    ap.add_argument("--csv-days", type=float, default=2.0)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})       # one core
    report = {"filter": filter_rate(farm_stream(args.days)), "goal_contacts_per_s": 200_000,
              "cli_replay": cli_rate(args.csv_days)}
    report["goal_met"] = report["filter"]["contacts_per_s"] >= 200_000
    print(json.dumps(report))


if __name__ == "__main__":
    main()
