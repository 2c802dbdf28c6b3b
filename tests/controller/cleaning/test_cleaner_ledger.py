"""The cleaner's progress survives a reopen of the ledger, trace by run; a version-4 ledger upgrades."""
from __future__ import annotations

import sqlite3

import numpy as np

from controller.cleaning.ledger import Progress
from controller.store import MIGRATIONS, Store


def test_progress_and_trace_survive_a_reopen_and_runs_never_mix(tmp_path):
    store = Store(tmp_path / "l.db")
    assert store.cleaner_progress() is None and store.next_cleaner_run() == 1
    first = Progress("fp1", 1, b"\x01\x02", 17, "cleaning", "clean", 0.25, 100.0)
    store.save_cleaner(first, np.array([[0.0, 0.0], [1.0, 0.5]]))
    store.save_cleaner(Progress("fp1", 1, b"\x01\x03", 18, "lost", "clean", 0.26, 105.0), np.array([[2.0, 1.0]]))
    assert store.next_cleaner_run() == 2
    store.save_cleaner(Progress("fp2", 2, None, 0, "docked", None, 0.0, 110.0), np.array([[9.0, 9.0]]))
    store.close()
    store = Store(tmp_path / "l.db")
    assert store.cleaner_progress() == Progress("fp2", 2, None, 0, "docked", None, 0.0, 110.0)
    assert np.allclose(store.cleaner_trace(1), [[0, 0], [1, 0.5], [2, 1]])
    assert np.allclose(store.cleaner_trace(2), [[9, 9]]) and store.cleaner_trace(3).shape == (0, 2)
    assert store.next_cleaner_run() == 3


def test_a_version_4_ledger_gains_the_cleaner_tables(tmp_path):
    db = sqlite3.connect(tmp_path / "old.db")
    db.executescript(";".join(MIGRATIONS[:4]) + "; PRAGMA user_version = 4;")
    db.close()
    store = Store(tmp_path / "old.db")
    assert store.schema_version == len(MIGRATIONS) == 11 and store.cleaner_progress() is None
