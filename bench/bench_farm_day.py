"""The whole farm day (24 farm hours of the demo farm at 360x, ~4 min of wall time): the suite's
hil_tests/test_feeding_day.py, which runs half a day, run for the whole one (FISHFARM_HIL_DAY_H).

Run: ``.venv/bin/python bench/bench_farm_day.py`` (BENCH_FARM_DAY_H, default 24); prints one JSON
object: whether every check held, the run's summary line (episodes, demands, feeds, service
times, ledger against physical grams) and the wall time.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HOURS = float(os.environ.get("BENCH_FARM_DAY_H", "24"))


def main() -> int:
    started = time.monotonic()
    env = {**os.environ, "FISHFARM_HIL_DAY_H": repr(HOURS)}
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider",
                           "hil_tests/test_feeding_day.py"], cwd=ROOT, env=env, capture_output=True, text=True)
    summary = next((line.strip() for line in proc.stdout.splitlines() if " episodes, " in line), None)
    print(json.dumps({"farm_hours": HOURS, "passed": proc.returncode == 0, "summary": summary,
                      "wall_s": round(time.monotonic() - started, 1),
                      "failure": None if proc.returncode == 0 else proc.stdout.strip().splitlines()[-1:]}))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from bench import no_arguments

    no_arguments(__doc__)
    sys.exit(main())
