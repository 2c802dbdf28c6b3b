"""Weight surveys in the ledger: a survey and every fish it counted, one transaction."""
from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from controller.store import MIGRATIONS, Store


def test_a_survey_and_its_fish_are_kept_with_their_summary(tmp_path):
    store = Store(tmp_path / "ledger.db")
    lengths, weights = [10.0, 11.0, 12.5], [15.0, 20.0, 31.0]
    sid = store.add_survey("T1", 1000.0, "sparus_aurata", "OUT.json", lengths, weights, [0.9, 0.8, 0.7])
    [row] = store.surveys("T1")
    mean = sum(weights) / 3
    sd = (sum((w - mean) ** 2 for w in weights) / 2) ** 0.5
    assert (row.id, row.count, row.source) == (sid, 3, "OUT.json")
    assert row.mean_weight_g == pytest.approx(mean) and row.sd_weight_g == pytest.approx(sd)
    assert row.cv_pct == pytest.approx(100 * sd / mean) and row.mean_length_cm == pytest.approx(11.1666667)
    assert list(store.survey_weights(sid)) == weights
    store.close()
    again = Store(tmp_path / "ledger.db")                  # committed: another process reads it
    assert again.surveys("T1")[0] == row


def test_surveys_come_newest_first_within_the_range_asked_and_empty_ones_are_kept_but_not_listed(tmp_path):
    store = Store(tmp_path / "ledger.db")
    for t in (100.0, 300.0, 200.0):
        store.add_survey("T1", t, "sparus_aurata", f"s{t:g}", [10.0], [t / 10])
    store.add_survey("T2", 250.0, "sparus_aurata", "other tank", [10.0], [1.0])
    empty = store.add_survey("T1", 400.0, "sparus_aurata", "nothing seen", [], [])
    assert [s.t for s in store.surveys("T1")] == [300.0, 200.0, 100.0]
    assert [s.t for s in store.surveys("T1", since=150.0, until=300.0)] == [300.0, 200.0]
    assert [s.t for s in store.surveys("T1", limit=1)] == [300.0]
    row = store.db.execute("SELECT count, mean_weight_g FROM survey WHERE id = ?", (empty,)).fetchone()
    assert tuple(row) == (0, None)


@pytest.mark.parametrize(("lengths", "weights"), [([10.0], [0.0]), ([10.0, 11.0], [5.0]), ([np.nan], [5.0]),
                                                   ([10.0], [-1.0]), ([10.0], [np.inf])])
def test_a_fish_without_a_real_length_and_weight_writes_nothing(tmp_path, lengths, weights):
    store = Store(tmp_path / "ledger.db")
    with pytest.raises(ValueError):
        store.add_survey("T1", 1.0, "sparus_aurata", "bad", lengths, weights)
    assert store.db.execute("SELECT COUNT(*) FROM survey").fetchone()[0] == 0
    assert store.db.execute("SELECT COUNT(*) FROM survey_fish").fetchone()[0] == 0


def test_a_version_5_ledger_gains_the_survey_tables_and_keeps_its_rows(tmp_path):
    path = tmp_path / "v5.db"
    db = sqlite3.connect(path)
    db.executescript(";".join(MIGRATIONS[:5]) + "; PRAGMA user_version = 5;")
    db.execute("INSERT INTO ration (tank, date, grams, pellet_mm, source, t) VALUES ('T1', 'd', 5, 1, 'config', 0)")
    db.commit()
    db.close()
    store = Store(path)
    assert store.schema_version == len(MIGRATIONS) == 11
    assert store.surveys_asked() == []
    assert store.ration("T1", "d")["grams"] == 5 and store.surveys("T1") == []
