"""Shutdown time of the real ``fishfarm run`` per phase of its life: wall seconds from the signal
to the process's exit (reaped), median and max over a few runs, SIGINT to the process group (a
terminal's Ctrl-C) and SIGTERM alternating. Phases as in tests/controller/test_shutdown.py.

Run: ``.venv/bin/python bench/bench_shutdown.py`` (BENCH_SHUTDOWN_RUNS, default 4 per phase);
prints one JSON object.
"""
from __future__ import annotations

import json
import os
import signal
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.controller.shutdown_rig import PHASES, RunningController  # noqa: E402

RUNS = int(os.environ.get("BENCH_SHUTDOWN_RUNS", "4"))
GOAL_S = 5.0


def one(phase: str, sig: int) -> dict:
    rc = RunningController(Path(tempfile.mkdtemp(prefix=f"bench-stop-{phase}-")), phase, speed=5.0)
    try:
        rc.reach()
        code = rc.wait_exit(rc.send(sig))
        clean = rc.ledger_clean() is None or (phase == "starting" and not rc.db.exists())
        return {"s": rc.exit_s, "ok": code == 0 and clean and not rc.sim_alive()}
    finally:
        rc.kill()


def main() -> dict:
    out, goal_met = {}, True
    for phase in PHASES:
        runs = [one(phase, (signal.SIGINT, signal.SIGTERM)[i % 2]) for i in range(RUNS)]
        times = [r["s"] for r in runs]
        ok = all(r["ok"] for r in runs) and max(times) < GOAL_S
        goal_met &= ok
        out[phase] = {"runs": len(runs), "median_s": round(statistics.median(times), 3),
                      "max_s": round(max(times), 3), "clean": all(r["ok"] for r in runs)}
    return {"phases": out, "goal_s": GOAL_S, "goal_met": goal_met}


if __name__ == "__main__":
    print(json.dumps(main()))
