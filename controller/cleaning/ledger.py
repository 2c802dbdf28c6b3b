"""The pond cleaner's progress in the ledger: a mixin of ``controller.store.Store`` (its
connection, lock and ``_write``), as ``controller.records`` is.

- ``cleaner``: one row: the plan's ``fingerprint`` (pond outline, keep-outs, brush, body, cell,
  plan parameters: a changed pond starts a fresh map), the ``run`` (cleaning runs begun, ever),
  the coverage ``map`` (``CoverageMap.to_bytes``), the ``path_index`` reached on the coverage
  path, and the state, mission and coverage last saved. A restart — even after SIGKILL — resumes
  from it; what was swept since the last save (a few farm seconds) is swept again.
- ``cleaner_trace``: the path followed, for ``fishfarm cleaner map``: per save, the poses since
  the previous one as float32 (x, y) pairs in metres, thinned to a few centimetres apart.
"""
from __future__ import annotations

import logging
import sqlite3
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

log = logging.getLogger("fishfarm.cleaner")

MIGRATION_5 = """
    CREATE TABLE cleaner (
        id          INTEGER PRIMARY KEY CHECK (id = 1),
        fingerprint TEXT NOT NULL,
        run         INTEGER NOT NULL,
        map         BLOB,
        path_index  INTEGER NOT NULL,
        state       TEXT NOT NULL,
        mission     TEXT,
        coverage    REAL NOT NULL,
        t           REAL NOT NULL
    );
    CREATE TABLE cleaner_trace (
        id    INTEGER PRIMARY KEY,
        run   INTEGER NOT NULL,
        t     REAL NOT NULL,
        xy    BLOB NOT NULL
    );
    CREATE INDEX cleaner_trace_run ON cleaner_trace (run, id)
"""
"""4 -> 5: the pond cleaner's coverage map, path index and trace."""


@dataclass(frozen=True)
class Progress:
    fingerprint: str
    run: int
    map: bytes | None
    path_index: int
    state: str
    mission: str | None
    coverage: float
    t: float


class CleanerRecords:
    db: sqlite3.Connection
    _lock: threading.RLock

    def cleaner_progress(self) -> Progress | None:
        row = self.db.execute("SELECT * FROM cleaner WHERE id = 1").fetchone()
        if row is None:
            return None
        fields = dict(row)
        fields.pop("id")
        return Progress(**fields)

    def next_cleaner_run(self) -> int:
        """A run number never used: a fresh map's trace never mixes with an older one's."""
        row = self.db.execute("SELECT MAX(r) FROM (SELECT MAX(run) AS r FROM cleaner "
                              "UNION ALL SELECT MAX(run) FROM cleaner_trace)").fetchone()
        return (row[0] or 0) + 1

    def save_cleaner(self, progress: Progress, trace: np.ndarray | None = None) -> None:
        """The progress, and the poses followed since the last save, in one commit."""
        with self.transaction() as db:
            db.execute(
                "INSERT INTO cleaner (id, fingerprint, run, map, path_index, state, mission, coverage, t) "
                "VALUES (1, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (id) DO UPDATE SET "
                "fingerprint = excluded.fingerprint, run = excluded.run, map = excluded.map, "
                "path_index = excluded.path_index, state = excluded.state, mission = excluded.mission, "
                "coverage = excluded.coverage, t = excluded.t",
                (progress.fingerprint, progress.run, progress.map, progress.path_index, progress.state,
                 progress.mission, progress.coverage, progress.t))
            if trace is not None and len(trace):
                db.execute("INSERT INTO cleaner_trace (run, t, xy) VALUES (?, ?, ?)",
                           (progress.run, progress.t, np.asarray(trace, "<f4").reshape(-1, 2).tobytes()))

    def cleaner_trace(self, run: int) -> np.ndarray:
        """(N, 2) poses (m) the cleaner followed in ``run``, in order."""
        rows = self.db.execute("SELECT xy FROM cleaner_trace WHERE run = ? ORDER BY id", (run,)).fetchall()
        if not rows:
            return np.zeros((0, 2))
        return np.frombuffer(b"".join(r["xy"] for r in rows), "<f4").reshape(-1, 2).astype(float)


@dataclass(frozen=True)
class Resumed:
    follower: object
    map: object
    run: int
    state: str
    mission: str | None


def resume(store, course, plan, map_from_bytes: Callable, *, estop_standing: bool,
           autostart: bool) -> Resumed:
    """Where a (re)started controller takes the cleaner up. The ledger's map and path index if they
    were made for this plan (same fingerprint), else a fresh run. A mission that stood (cleaning,
    returning, lost, fault...) is taken up again from ``localising`` (the robot may have drifted);
    an operator's stop stays ``manual``; an e-stop that stands starts in ``estop``. ``autostart``
    begins cleaning from the dock when the map is not complete."""
    saved = store.cleaner_progress()
    cmap = None
    if saved is not None and saved.fingerprint == course.fingerprint:
        try:
            cmap = map_from_bytes(saved.map) if saved.map is not None else course.fresh_map()
        except ValueError as exc:
            log.warning("cleaner: the saved coverage map cannot be used (%s): a fresh map", exc)
    if cmap is not None:
        last = len(plan.path) - 1
        follower = course.follow(plan.path, min(saved.path_index, last))
        follower.done = saved.path_index > last    # the run was finished
        run, mission = saved.run, saved.mission
        state = "manual" if saved.state == "manual" else ("localising" if mission else "docked")
    else:
        if saved is not None and saved.fingerprint != course.fingerprint:
            log.warning("cleaner: the pond or its plan changed since the saved map: a fresh map")
        cmap, follower, run = course.fresh_map(), course.follow(plan.path, 0), store.next_cleaner_run()
        state, mission = "docked", None
    if state == "docked" and autostart and not follower.done:
        state, mission = "localising", "clean"
    if estop_standing:
        state = "estop"
    return Resumed(follower, cmap, run, state, mission)
