"""bench/diag_rations_replay.py: a kept run's rations planned again and judged against the truth it
is given. The truth here is made from the errors wanted (true = planned / (1 + error)), so the counts
the tool prints are known before it runs."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from controller.config import load_config
from controller.feeding.rations import Rations, load_species, species_file
from controller.store import Store

ROOT = Path(__file__).resolve().parents[1]
DAY = 86_400.0
T0 = 1_780_012_800.0            # a farm midnight (UTC; the demo's offset moves the dates alike)


def kept_run(tmp_path: Path) -> tuple[Path, list[tuple[str, str, float]]]:
    """A kept run's directory: the demo config, a ledger with two surveys of T1 a week apart and the
    rations of the days after, planned as the controller plans them; (tank, date, mean weight)."""
    run = tmp_path / "run"
    run.mkdir()
    text = (ROOT / "config" / "farm.toml").read_text().replace('path = "var/fishfarm.db"',
                                                               f'path = "{run / "ledger.db"}"')
    (run / "controller.toml").write_text(text)
    cfg = load_config(run / "controller.toml")
    store = Store(run / "ledger.db", cfg.surveys.min_weighed_fish)
    rng = np.random.default_rng(3)
    for week, mean_cm in ((0, 10.0), (1, 10.6)):
        lengths = rng.normal(mean_cm, 0.7, 60)
        store.add_survey("T1", T0 + week * 7 * DAY + 3600, "sparus_aurata", "", lengths, 0.02263 * lengths ** 3.032)
    rations = Rations(cfg, load_species(species_file(cfg.path)), store)
    planned = []
    for day in range(8, 13):
        t = T0 + day * DAY + 6 * 3600
        rations.today("T1", t)
        planned.append(("T1", rations.date(t), rations.plan("T1", t).mean_weight_g))
    store.close()
    return run, planned


def test_the_replay_counts_the_tank_days_within_5_percent_of_the_truth_it_is_given(tmp_path):
    run, planned = kept_run(tmp_path)
    errors = [-0.06, -0.02, 0.0, 0.049, 0.051]           # planned against true: 3 within 5 %
    judge = {"rations": [{"tank": tank, "date": date, "mean_g": round(w, 2), "true_mean_g": w / (1 + e)}
                         for (tank, date, w), e in zip(planned, errors, strict=True)]
             + [{"tank": "T2", "date": "2026-01-01", "mean_g": 1.0, "true_mean_g": 1.0}]}   # no such row: left out
    (tmp_path / "judge.json").write_text(json.dumps(judge))
    got = subprocess.run([sys.executable, str(ROOT / "bench" / "diag_rations_replay.py"), str(run),
                          str(tmp_path / "judge.json")], capture_output=True, text=True, timeout=120)
    assert got.returncode == 0, got.stderr
    [out] = json.loads(got.stdout)["runs"]
    assert out["tank_days"] == 5 and out["within_5_pct"] == 3
    assert abs(out["mean_pct"] - 100 * np.mean(errors)) < 1e-3
    assert abs(out["worst_pct"] - (-6.0)) < 1e-3
    assert out["logged_max_dev_pct"] < 0.05                    # the logged weights, rounded to 0.01 g
    # the kept ledger itself is left as it was: the replay plans on a copy
    kept = Store(run / "ledger.db")
    try:
        assert kept.db.execute("SELECT COUNT(*) FROM ration").fetchone()[0] == 5
    finally:
        kept.close()


def test_a_run_given_without_its_judge_is_refused():
    got = subprocess.run([sys.executable, str(ROOT / "bench" / "diag_rations_replay.py"), "somewhere"],
                         capture_output=True, text=True, timeout=60)
    assert got.returncode == 2 and "judge" in got.stderr
