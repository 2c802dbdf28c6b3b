"""Feeding benchmarks on the real processes (simulator + controller over Zenoh, Modbus TCP and ptys).

- latency: real time (speed 1); the robot parked at one tank whose fish keep asking; for every
  served demand, the auger's start (the simulated PLC's own clock) minus the time stamp of the
  contact that raised the demand — what the controller adds beyond the filter's evidence.
- tanks500: one controller with 500 simulated tanks at the default (nominal) contact rates, real
  time; the controller process's CPU time over wall time.
- day: a simulated 24 h farm day at high speed; wall time, and whether its goals held.

Run: ``.venv/bin/python bench/bench_feeding.py [latency|tanks500|day ...]``; prints one JSON object.
"""
from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil_tests.evidence import judge  # noqa: E402
from hil_tests.farm import HilFarm  # noqa: E402

LATENCY_WALL_S = float(os.environ.get("BENCH_LATENCY_S", "600"))
TANKS500_WALL_S = float(os.environ.get("BENCH_TANKS500_S", "120"))
DAY_SPEED = float(os.environ.get("BENCH_DAY_SPEED", "2000"))


def cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def pct(values, q):
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))] if values else None


def latency() -> dict:
    one_tank = [{"id": "T1", "stock": 100_000, "mean_weight_g": 50.0, "position_m": 2.0, "sensors": ["a", "b"]}]
    overrides = {
        "tanks": one_tank,
        "feeding": {"portion_g": 5.0, "min_portion_g": 1.0},
        "demand": {"repeat_s": 2.0, "repeat_contacts": 2},
        "sim": {"fish": {"ration_pct_day": 20.0, "hunger_threshold_g": 5.0, "initial_hunger": 2.0,
                         "sated_fraction": 0.01, "rate_hz": [1.5, 2.0], "duration_s": [600.0, 600.0],
                         "rest_s": 0.0, "bursts_per_hour": 0.0}},
    }
    farm = HilFarm(Path(tempfile.mkdtemp(prefix="bench-latency-")), speed=1.0, overrides=overrides)
    try:
        farm.start_sim()
        farm.start_controller()
        farm.wait_controller_up()
        farm.sleep_until_farm(farm.farm_now() + LATENCY_WALL_S)
    finally:
        farm.stop()
    starts = {r["tag"]: r["t_start"] for r in farm.truth() if r["kind"] == "auger_run"}
    with farm.ledger() as db:
        rows = db.execute("SELECT d.t AS raised, f.tag, f.seq FROM feed f JOIN demand d ON d.id = f.demand_id "
                          "WHERE f.phase = 'done' AND d.source = 'demand' ORDER BY f.seq").fetchall()
    # the first feed includes the carriage's trip from the food box to the tank: leave it out
    lat_ms = [1000.0 * (starts[r["tag"]] - r["raised"]) for r in rows[1:] if r["tag"] in starts]
    if not lat_ms:
        return {"samples": 0, "goal_met": False, "error": "no demand was served at the parked robot"}
    return {"samples": len(lat_ms), "p50_ms": round(pct(lat_ms, 0.5), 1), "p99_ms": round(pct(lat_ms, 0.99), 1),
            "max_ms": round(max(lat_ms), 1), "goal_p99_ms": 50.0, "goal_met": pct(lat_ms, 0.99) <= 50.0}


def tanks500() -> dict:
    tanks = [{"id": f"T{i}", "stock": 2000, "mean_weight_g": 25.0, "position_m": 2.0 + 0.8 * i,
              "sensors": [f"T{i}-a", f"T{i}-b"]} for i in range(1, 501)]
    overrides = {"tanks": tanks, "sim": {"rail": {"rail_length_m": 410.0}}}
    farm = HilFarm(Path(tempfile.mkdtemp(prefix="bench-500-")), speed=1.0, overrides=overrides)
    try:
        farm.start_sim()
        farm.start_controller()
        farm.wait_controller_up()
        time.sleep(5.0)                          # start-up work (rations for 500 tanks) is not the steady state
        c0, s0, w0 = cpu_s(farm.ctl_proc.pid), cpu_s(farm.sim_proc.pid), time.monotonic()
        time.sleep(TANKS500_WALL_S)
        c1, s1, w1 = cpu_s(farm.ctl_proc.pid), cpu_s(farm.sim_proc.pid), time.monotonic()
        farm.check_alive()
    finally:
        farm.stop()
    hub = [r for r in farm.truth() if r["kind"] == "contact_hub"]
    contacts = sum(r["sent"] for r in hub)
    share = (c1 - c0) / (w1 - w0)
    return {"tanks": 500, "wall_s": round(w1 - w0, 1), "controller_cpu_share": round(share, 4),
            "simulator_cpu_share": round((s1 - s0) / (w1 - w0), 4), "goal_share": 0.25,
            "goal_met": share <= 0.25, "hub_lines_sent": contacts}


def day() -> dict:
    farm = HilFarm(Path(tempfile.mkdtemp(prefix="bench-day-")), speed=DAY_SPEED)
    started = time.monotonic()
    try:
        farm.start_sim()
        farm.start_controller()
        up = farm.wait_controller_up()
        day_began = time.monotonic()
        farm.sleep_until_farm(up + 86_400.0)
        day_wall = time.monotonic() - day_began
        farm.check_alive()
    finally:
        farm.stop()
    truth = [r for r in farm.truth() if r["t"] >= up + 120.0 or r["kind"] == "auger_run"]
    with farm.ledger() as db:
        verdict = judge(db, truth, up + 86_400.0)
    return {"speed": DAY_SPEED, "day_wall_s": round(day_wall, 1),
            "with_startup_wall_s": round(time.monotonic() - started, 1), "goal_wall_s": 60.0,
            "goal_met": day_wall <= 60.0 and not verdict.problems, "problems": verdict.problems[:5],
            "summary": verdict.summary(),
            "service_p50_s": round(statistics.median(verdict.service_s), 1) if verdict.service_s else None,
            "service_max_s": round(max(verdict.service_s), 1) if verdict.service_s else None}


PARTS = {"latency": latency, "tanks500": tanks500, "day": day}


def main(argv: list[str]) -> None:
    chosen = argv or list(PARTS)
    print(json.dumps({name: PARTS[name]() for name in chosen}, indent=2))


if __name__ == "__main__":
    from bench import no_arguments

    main(no_arguments(__doc__, takes=PARTS))
