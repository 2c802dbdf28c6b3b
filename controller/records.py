"""What operators do and are held to, in the ledger: the audit of every override, stock events,
paused tanks, and each alarm's standing state. A mixin of ``controller.store.Store`` (its
connection, lock and ``_write``), kept apart so the ledger's feed logic stays readable.

- ``audit``: one row per override, accepted or refused, e-stop included: when, the authenticated
  ``user`` (NULL when the transport could not say), the ``operator`` the payload claimed, the
  command, the payload as received (escaped, bounded; NULL when it was unreadable), where it came
  from, and the result (``ok`` or the error replied).
- ``stock_event``: mortality, harvest and transfers; a tank's stock is the config's plus these.
- ``tank_pause``: a row while a tank is paused (its demands are not served); survives restarts.
- ``alarm_state``: one row per alarm ``(source, kind)``: severity, active, acknowledged (by whom,
  when), first and last seen, count. The ``alarm`` table keeps the history of changes.
"""
from __future__ import annotations

import sqlite3
import threading

MIGRATION_4 = """
    CREATE TABLE audit (
        id        INTEGER PRIMARY KEY,
        t         REAL NOT NULL,
        user      TEXT,
        operator  TEXT,
        command   TEXT NOT NULL,
        payload   TEXT,
        origin    TEXT NOT NULL,
        ok        INTEGER NOT NULL,
        result    TEXT NOT NULL,
        reply     TEXT
    );
    CREATE INDEX audit_t ON audit (t);
    CREATE TABLE stock_event (
        id        INTEGER PRIMARY KEY,
        t         REAL NOT NULL,
        tank      TEXT NOT NULL,
        kind      TEXT NOT NULL,
        count     INTEGER NOT NULL CHECK (count > 0),
        to_tank   TEXT,
        who       TEXT NOT NULL,
        reason    TEXT NOT NULL DEFAULT ''
    );
    CREATE INDEX stock_event_tank ON stock_event (tank);
    CREATE INDEX stock_event_to ON stock_event (to_tank);
    CREATE TABLE tank_pause (
        tank      TEXT PRIMARY KEY,
        t         REAL NOT NULL,
        who       TEXT NOT NULL,
        reason    TEXT NOT NULL DEFAULT ''
    );
    CREATE TABLE alarm_state (
        source    TEXT NOT NULL,
        kind      TEXT NOT NULL,
        severity  TEXT NOT NULL,
        text      TEXT NOT NULL,
        active    INTEGER NOT NULL,
        t         REAL NOT NULL,
        first_t   REAL NOT NULL,
        last_t    REAL NOT NULL,
        count     INTEGER NOT NULL,
        acked_by  TEXT,
        acked_t   REAL,
        PRIMARY KEY (source, kind)
    );
    INSERT INTO alarm_state (source, kind, severity, text, active, t, first_t, last_t, count, acked_by, acked_t)
    SELECT l.source, l.kind, l.severity, l.text, l.active, l.t,
           (SELECT MIN(a.t) FROM alarm a WHERE a.source = l.source AND a.kind = l.kind),
           COALESCE((SELECT MAX(a.t) FROM alarm a WHERE a.source = l.source AND a.kind = l.kind
                     AND a.active = 1), l.t),
           (SELECT COUNT(*) FROM alarm a WHERE a.source = l.source AND a.kind = l.kind AND a.active = 1),
           CASE WHEN l.active = 0 THEN 'cleared before acknowledgement existed' END,
           CASE WHEN l.active = 0 THEN l.t END
    FROM alarm l JOIN (SELECT source, kind, MAX(id) AS id FROM alarm GROUP BY source, kind) m ON l.id = m.id
"""
"""3 -> 4. Alarms of older ledgers: count is their raises and severity changes in the history;
one that stood cleared is taken as acknowledged (nobody could acknowledge it then), so an
upgrade does not fill ``status`` with every alarm the farm ever had."""

ALARM_FIELDS = ("source", "kind", "severity", "text", "active", "t", "first_t", "last_t", "count",
                "acked_by", "acked_t")


class Records:
    db: sqlite3.Connection
    _lock: threading.RLock

    # -- audit ----------------------------------------------------------------
    def add_audit(self, *, t: float, user: str | None, operator: str | None, command: str,
                  payload: str | None, origin: str, ok: bool, result: str, reply: str | None = None) -> int:
        return self._write(
            "INSERT INTO audit (t, user, operator, command, payload, origin, ok, result, reply) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (t, user, operator, command, payload, origin, int(ok), result, reply)).lastrowid

    def add_audits(self, rows: list[dict]) -> None:
        """Several audit rows (``add_audit``'s fields) in one transaction: one fsync."""
        with self.transaction() as db:
            db.executemany(
                "INSERT INTO audit (t, user, operator, command, payload, origin, ok, result, reply) "
                "VALUES (:t, :user, :operator, :command, :payload, :origin, :ok, :result, :reply)", rows)

    def audit(self, *, since: float | None = None, operator: str | None = None) -> list[sqlite3.Row]:
        """Rows oldest first; ``operator`` matches the authenticated user or the claimed name."""
        sql, args = "SELECT * FROM audit WHERE 1 = 1", []
        if since is not None:
            sql += " AND t >= ?"
            args.append(since)
        if operator is not None:
            sql += " AND (user = ? OR operator = ?)"
            args += [operator, operator]
        return self.db.execute(sql + " ORDER BY id", args).fetchall()

    # -- stock ----------------------------------------------------------------
    def add_stock_event(self, *, t: float, tank: str, kind: str, count: int, to_tank: str | None,
                        who: str, reason: str = "") -> int:
        return self._write(
            "INSERT INTO stock_event (t, tank, kind, count, to_tank, who, reason) VALUES (?, ?, ?, ?, ?, ?, ?)",
            (t, tank, kind, count, to_tank, who, reason)).lastrowid

    def stock_change(self, tank: str) -> int:
        """Fish in (transfers to ``tank``) minus fish out (its mortality, harvests, transfers away)."""
        row = self.db.execute(
            "SELECT COALESCE((SELECT SUM(count) FROM stock_event WHERE to_tank = ?), 0) "
            "- COALESCE((SELECT SUM(count) FROM stock_event WHERE tank = ?), 0)", (tank, tank)).fetchone()
        return row[0]

    def stock_events(self) -> list[sqlite3.Row]:
        return self.db.execute("SELECT * FROM stock_event ORDER BY id").fetchall()

    # -- paused tanks -----------------------------------------------------------
    def pause_tank(self, tank: str, t: float, who: str, reason: str = "") -> bool:
        """True when the tank was not paused already (a second pause keeps the first's record)."""
        return self._write("INSERT OR IGNORE INTO tank_pause (tank, t, who, reason) VALUES (?, ?, ?, ?)",
                           (tank, t, who, reason)).rowcount == 1

    def resume_tank(self, tank: str) -> bool:
        return self._write("DELETE FROM tank_pause WHERE tank = ?", (tank,)).rowcount == 1

    def paused_tanks(self) -> dict[str, sqlite3.Row]:
        return {r["tank"]: r for r in self.db.execute("SELECT * FROM tank_pause")}

    # -- alarm states -------------------------------------------------------------
    def save_alarm_state(self, *, history: bool = False, **fields) -> None:
        """An alarm's state now; with ``history``, its row in the ``alarm`` history too, in the
        same commit (raised, severity changed, cleared)."""
        values = tuple(int(v) if isinstance(v, bool) else v for v in (fields[f] for f in ALARM_FIELDS))
        with self.transaction() as db:
            db.execute(f"INSERT OR REPLACE INTO alarm_state ({', '.join(ALARM_FIELDS)}) "
                       f"VALUES ({', '.join('?' * len(ALARM_FIELDS))})", values)
            if history:
                db.execute("INSERT INTO alarm (source, kind, t, severity, text, active) VALUES (?, ?, ?, ?, ?, ?)",
                           (fields["source"], fields["kind"], fields["t"], fields["severity"],
                            fields["text"], int(fields["active"])))

    def alarm_states(self) -> list[sqlite3.Row]:
        return self.db.execute("SELECT * FROM alarm_state ORDER BY first_t, source, kind").fetchall()
