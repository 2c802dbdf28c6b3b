"""Shutdown time of the real ``fishfarm run`` per phase of its life: wall seconds from the signal
to the process's exit (reaped), median and max over a few runs, SIGINT to the process group (a
terminal's Ctrl-C) and SIGTERM alternating. Phases as in tests/controller/test_shutdown.py.
``probe``: like the outside probe of issue 6 — the demo farm (speed 1) signalled at a random moment
0–8 s after launch (starting, homing, serving), SIGINT to the group or SIGTERM; how many did not
end by themselves within 5 s, and the time's median and max.

Run: ``.venv/bin/python bench/bench_shutdown.py`` (BENCH_SHUTDOWN_RUNS, default 4 per phase);
prints one JSON object.
"""
from __future__ import annotations

import json
import os
import random
import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.controller.shutdown_rig import PHASES, RunningController  # noqa: E402

RUNS = int(os.environ.get("BENCH_SHUTDOWN_RUNS", "4"))
PROBES = int(os.environ.get("BENCH_SHUTDOWN_PROBES", "20"))
GOAL_S = 5.0


def one(phase: str, sig: int) -> dict:
    rc = RunningController(Path(tempfile.mkdtemp(prefix=f"bench-stop-{phase}-")), phase, speed=5.0)
    try:
        rc.reach()
        code = rc.wait_exit(rc.send(sig))
        clean = rc.ledger_clean() is None or (phase == "starting" and not rc.db.exists())
        return {"s": rc.exit_s, "ok": code == 0 and clean and not rc.sim_alive() and not rc.leftovers()}
    finally:
        rc.kill()


def probe(rng: random.Random, sig: int) -> dict:
    rc = RunningController(Path(tempfile.mkdtemp(prefix="bench-stop-probe-")), "feeding", speed=1.0)
    try:
        rc.start()
        time.sleep(rng.uniform(0.0, 8.0))
        if rc.proc.poll() is not None:
            return {"s": None, "ok": False}
        sent = rc.send(sig)
        try:
            code = rc.wait_exit(sent, timeout_s=GOAL_S)
        except AssertionError:                    # still alive at 5 s: SIGKILLed by wait_exit
            return {"s": None, "ok": False}
        # a signal in the interpreter's first moments, before anything was started, kills it outright
        early = code == -sig and "fishfarm sim, pid" not in rc.log() and not rc.db.exists()
        why = [f"exit {code}"] if code != 0 and not early else []
        if rc.db.exists() and rc.ledger_clean() is not None:
            why.append(rc.ledger_clean())
        if rc.leftovers():
            why.append(f"left behind: {rc.leftovers()}")
        if why:
            print(f"probe: {'; '.join(why)}\n{rc.log()[-2000:]}", file=sys.stderr)
        return {"s": rc.exit_s, "ok": not why}
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
    rng = random.Random(6)
    probes = [probe(rng, (signal.SIGINT, signal.SIGTERM)[i % 2]) for i in range(PROBES)]
    times = [p["s"] for p in probes if p["s"] is not None]
    stuck = sum(p["s"] is None for p in probes)
    goal_met &= stuck == 0 and all(p["ok"] for p in probes)
    out["probe"] = {"runs": len(probes), "stuck": stuck, "unclean": sum(not p["ok"] for p in probes),
                    "median_s": round(statistics.median(times), 3) if times else None,
                    "max_s": round(max(times), 3) if times else None}
    return {"phases": out, "goal_s": GOAL_S, "goal_met": goal_met, "python": sys.version.split()[0]}


if __name__ == "__main__":
    from bench import no_arguments

    no_arguments(__doc__)
    print(json.dumps(main()))
