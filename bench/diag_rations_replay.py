"""The rations of a kept grow-out planned again by today's code, against the simulator's fish: an
estimator change judged on the same surveys and feeds in seconds instead of a 10-minute run.

A run of ``bench/bench_growout.py`` with ``BENCH_GROWOUT_KEEP=DIR`` leaves its ledger and its
controller's config in DIR, and prints the judge's JSON (``rations``: per tank and farm day, the
true mean weight). For every ration row of the ledger the judge has, the controller's own
``Rations.plan`` (controller/feeding/rations.py) runs again on a copy of the ledger at the time the
row was planned, and its mean weight is compared with the true one. The copy is opened as the
controller opens its ledger (``[surveys] min_weighed_fish``); the water's temperature is the
config's (the run's thermometer readings are not kept).

Prints one JSON object: per run, tank-days judged, how many within 5 % of the true biomass (the
issue's goal), the error's mean, sd and worst, and ``logged_max_dev_pct``: how far the replayed
weights lie from the ones the run logged (the judge's ``mean_g``; ~0.04 % of rounding when today's
code plans as the run's did).

Run: ``.venv/bin/python bench/diag_rations_replay.py KEEP_DIR JUDGE.json [KEEP_DIR JUDGE.json ...]``
"""
from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from controller.config import load_config  # noqa: E402
from controller.feeding.rations import Rations, load_species, species_file  # noqa: E402
from controller.store import Store  # noqa: E402

WITHIN_PCT = 5.0


def replay(run_dir: Path, judge: dict) -> dict:
    """The replayed rations of one kept run against its judge's truth (module docstring)."""
    cfg = load_config(run_dir / "controller.toml")
    truth = {(r["tank"], r["date"]): r for r in judge["rations"]}
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in ("", "-wal", "-shm"):
            src = run_dir / f"ledger.db{suffix}"
            if src.exists():
                shutil.copy(src, Path(tmp) / f"ledger.db{suffix}")
        store = Store(Path(tmp) / "ledger.db", cfg.surveys.min_weighed_fish)
        try:
            rations = Rations(cfg, load_species(species_file(cfg.path)), store)
            errors, devs = [], []
            for row in store.db.execute("SELECT tank, date, t FROM ration ORDER BY t"):
                true = truth.get((row["tank"], row["date"]))
                if true is None:
                    continue
                planned = rations.plan(row["tank"], row["t"]).mean_weight_g
                errors.append(100.0 * (planned / true["true_mean_g"] - 1.0))
                devs.append(abs(100.0 * (planned / true["mean_g"] - 1.0)))
        finally:
            store.close()
    if not errors:
        return {"run": str(run_dir), "tank_days": 0}
    return {"run": str(run_dir), "tank_days": len(errors),
            "within_5_pct": sum(abs(e) <= WITHIN_PCT for e in errors),
            "mean_pct": round(statistics.fmean(errors), 3), "sd_pct": round(statistics.pstdev(errors), 3),
            "worst_pct": round(max(errors, key=abs), 3), "logged_max_dev_pct": round(max(devs), 3)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", metavar="KEEP_DIR JUDGE.json",
                    help="kept run directories and their judge's JSON")
    args = ap.parse_args(argv)
    if len(args.runs) % 2:
        ap.error("give each kept run directory with its judge's JSON")
    out = []
    for run_dir, judged in zip(args.runs[::2], args.runs[1::2], strict=True):
        out.append(replay(Path(run_dir), json.loads(Path(judged).read_text())))
    print(json.dumps({"runs": out}))


if __name__ == "__main__":
    main()
