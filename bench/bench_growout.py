"""Issue 10's grow-out (hil_tests/growout.py): the demo farm's 8 tanks surveyed weekly, the real
controller process, vision workers in processes of their own, fish growing by a known model, on an
elastic clock. Goal: 60 farm days in <= 10 min of wall.

Figures (one JSON object): ``wall_s`` and ``wall_per_day_s``; ``wall_by_reason`` (where the wall
went: fast, fish asking, the robot's states, surveying); ``surveys`` (per survey the controller's
mean weight and biomass against the simulator's: goal within 5 %); ``intervals`` (per pair of a
tank's consecutive surveys the reported FCR and SGR against the simulator's); ``rations`` (per
ration planned from a survey, the biomass it rests on — the tank's growth fit that day — against the
simulator's: goal within 5 %); ``fits`` (per tank the SGR and FCR fitted to its surveys against the
simulator's over the fit's window: goal within 5 %);
``demands`` (every served demand's wait; those overlapping a survey visit: none over 60 s);
``feeding`` (the farm-day judge: hil_tests/evidence.py).

Run: ``.venv/bin/python bench/bench_growout.py`` (BENCH_GROWOUT_DAYS, default 60;
BENCH_GROWOUT_PAIRS, BENCH_GROWOUT_MEALS, BENCH_GROWOUT_WORKERS, BENCH_GROWOUT_SLOW,
BENCH_GROWOUT_FAST); BENCH_GROWOUT_KEEP=DIR keeps the run's files.
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hil_tests import growout  # noqa: E402


def main() -> int:
    keep = os.environ.get("BENCH_GROWOUT_KEEP")
    work = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="fishfarm-growout-"))
    work.mkdir(parents=True, exist_ok=True)
    env = os.environ.get
    settings = {"pairs": int(env("BENCH_GROWOUT_PAIRS", growout.PAIRS)),
                "meals_per_day": float(env("BENCH_GROWOUT_MEALS", growout.MEALS_PER_DAY)),
                "fps": float(env("BENCH_GROWOUT_FPS", growout.FPS)),
                "fish_in_view": tuple(int(x) for x in env("BENCH_GROWOUT_FISH", "10,18").split(",")),
                "size": tuple(int(x) for x in env("BENCH_GROWOUT_SIZE", "{}x{}".format(*growout.SIZE)).split("x"))}
    _, out = growout.run(work, float(env("BENCH_GROWOUT_DAYS", "60")),
                         slow=float(env("BENCH_GROWOUT_SLOW", growout.SLOW)),
                         fast=float(env("BENCH_GROWOUT_FAST", growout.FAST)),
                         workers=int(env("BENCH_GROWOUT_WORKERS", growout.WORKERS)), **settings)
    out["goals"] = {"wall_s": "<= 600 for 60 days", "biomass_err_pct": "<= 5", "fcr_err_pct": "<= 5",
                    "sgr_err_pct": "<= 5", "over_60_during_visits": 0}
    out["load_avg"] = os.getloadavg()
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    from bench import no_arguments

    no_arguments(__doc__)
    sys.exit(main())
