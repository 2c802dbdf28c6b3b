"""Weight surveys in the ledger: a mixin of ``controller.store.Store`` (its connection, lock and
``_write``), as ``controller.records`` is.

- ``survey``: one row a survey of a tank: when (farm time), species, what it rests on (``source``:
  the OUT.json it came from, or the scheduler's job) and its summary — fish counted, mean and
  standard deviation of weight, mean length, coefficient of variation of weight.
- ``survey_fish``: every fish it counted (one per track in video): fork length, weight and score.

A survey and its fish are one transaction: a kill mid-write leaves neither.
"""
from __future__ import annotations

import math
import sqlite3
import threading
from dataclasses import dataclass

import numpy as np

MIGRATION_6 = """
    CREATE TABLE survey (
        id            INTEGER PRIMARY KEY,
        tank          TEXT NOT NULL,
        t             REAL NOT NULL,
        species       TEXT NOT NULL,
        source        TEXT NOT NULL,
        count         INTEGER NOT NULL,
        mean_weight_g REAL,
        sd_weight_g   REAL,
        mean_length_cm REAL,
        cv_pct        REAL
    );
    CREATE INDEX survey_tank_t ON survey (tank, t);
    CREATE TABLE survey_fish (
        survey     INTEGER NOT NULL REFERENCES survey (id),
        length_cm  REAL NOT NULL,
        weight_g   REAL NOT NULL,
        score      REAL
    );
    CREATE INDEX survey_fish_survey ON survey_fish (survey)
"""
"""5 -> 6: weight surveys and every fish they measured."""

MIGRATION_7 = """
    CREATE TABLE survey_asked (
        tank   TEXT PRIMARY KEY,
        t      REAL NOT NULL,
        pairs  INTEGER NOT NULL
    )
"""
"""6 -> 7: the surveys operators asked for and that have not been recorded or given up yet: a
restart asks them again (a kill lost them, and the operator had been told ok)."""


@dataclass(frozen=True)
class SurveyRow:
    id: int
    tank: str
    t: float
    species: str
    source: str
    count: int
    mean_weight_g: float | None
    sd_weight_g: float | None
    mean_length_cm: float | None
    cv_pct: float | None


class SurveyRecords:
    db: sqlite3.Connection
    _lock: threading.RLock
    min_weighed = 1           # fish a survey counts to weigh its tank: set from [surveys] min_weighed_fish

    def ask_survey(self, tank: str, t: float, pairs: int) -> None:
        with self._lock:
            self._write("INSERT OR REPLACE INTO survey_asked (tank, t, pairs) VALUES (?, ?, ?)", (tank, t, pairs))

    def survey_answered(self, tank: str) -> None:
        """An operator's survey of ``tank`` recorded, or given up: not asked again after a restart."""
        with self._lock:
            self._write("DELETE FROM survey_asked WHERE tank = ?", (tank,))

    def surveys_asked(self) -> list[tuple[str, float, int]]:
        """(tank, asked at, pairs) of the operators' surveys still open, oldest first."""
        return [tuple(r) for r in self.db.execute("SELECT tank, t, pairs FROM survey_asked ORDER BY t, rowid")]

    def add_survey(self, tank: str, t: float, species: str, source: str, lengths_cm, weights_g,
                   scores=None) -> int:
        """Record a survey and its fish (one per fish counted); returns its id. An empty survey
        (no fish) is a result too: count 0, no means."""
        length = np.asarray(lengths_cm, float).ravel()
        weight = np.asarray(weights_g, float).ravel()
        score = np.full(len(weight), np.nan) if scores is None else np.asarray(scores, float).ravel()
        if not len(length) == len(weight) == len(score):
            raise ValueError("a length, a weight and a score for every fish")
        if not (np.all(np.isfinite(length) & (length > 0)) and np.all(np.isfinite(weight) & (weight > 0))):
            raise ValueError("every fish needs a positive, finite length and weight")
        n = len(weight)
        mean = float(weight.mean()) if n else None
        sd = float(weight.std(ddof=1)) if n > 1 else (0.0 if n else None)
        cv = 100.0 * sd / mean if n and mean > 0 else None
        with self.transaction() as db:
            cur = db.execute(
                "INSERT INTO survey (tank, t, species, source, count, mean_weight_g, sd_weight_g, "
                "mean_length_cm, cv_pct) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (tank, t, species, source, n, mean, sd, float(length.mean()) if n else None, cv))
            sid = cur.lastrowid
            db.executemany(
                "INSERT INTO survey_fish (survey, length_cm, weight_g, score) VALUES (?, ?, ?, ?)",
                [(sid, float(a), float(b), None if math.isnan(c) else float(c))
                 for a, b, c in zip(length, weight, score, strict=True)])
        return int(sid)

    def surveys(self, tank: str, *, since: float | None = None, until: float | None = None,
                with_fish: bool = False, limit: int | None = None, counted: bool | None = True) -> list[SurveyRow]:
        """The tank's surveys that weigh it — counted at least ``min_weighed`` fish (``[surveys]
        min_weighed_fish``; 1 until told) — newest first (``limit``: only that many); ``counted``
        False: those that counted fewer (none: cameras blocked, lights off, turbid water; a handful:
        a reef or a murky water hid most fish), None: all."""
        sql = "SELECT * FROM survey WHERE tank = ?" + {True: " AND count >= ?", False: " AND count < ?",
                                                       None: ""}[counted]
        args: list = [tank] + ([max(1, int(self.min_weighed))] if counted is not None else [])
        if since is not None:
            sql, args = sql + " AND t >= ?", [*args, since]
        if until is not None:
            sql, args = sql + " AND t <= ?", [*args, until]
        sql += " ORDER BY t DESC, id DESC" + (f" LIMIT {int(limit)}" if limit is not None else "")
        return [SurveyRow(**dict(r)) for r in self.db.execute(sql, args)]

    def survey_fish(self, survey_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(fork lengths cm, weights g) of every fish the survey counted, in the order recorded."""
        rows = self.db.execute("SELECT length_cm, weight_g FROM survey_fish WHERE survey = ? ORDER BY rowid",
                               (survey_id,)).fetchall()
        table = np.array(rows, float).reshape(-1, 2)
        return table[:, 0], table[:, 1]

    def survey_weights(self, survey_id: int) -> np.ndarray:
        return self.survey_fish(survey_id)[1]

    def same_fish_survey(self, tank: str, lengths_cm) -> SurveyRow | None:
        """The tank's survey, if any, whose fish have exactly these fork lengths: the same survey
        recorded again (the same pairs surveyed twice), which the growth fit would count twice."""
        length = np.sort(np.asarray(lengths_cm, float).ravel())
        if not len(length):
            return None
        for row in self.db.execute("SELECT * FROM survey WHERE tank = ? AND count = ? ORDER BY t DESC",
                                   (tank, len(length))):
            if np.allclose(np.sort(self.survey_fish(row["id"])[0]), length, rtol=0, atol=1e-9):
                return SurveyRow(**dict(row))
        return None
