"""The ledger: SQLite in WAL mode with synchronous=FULL, so a committed row survives a power cut.

What it holds: validated demands, feed intents and their outcomes, daily rations, alarms;
(controller.records) the audit of overrides, stock events, paused tanks and each alarm's state;
(controller.cleaning.ledger) the pond cleaner's coverage map, progress and trace; and
(controller.surveys.ledger) weight surveys with every fish they counted; (controller.feed_records)
the feed rows' reads and writes.
Exactly-once dispensing rests on one rule: a feed row is committed in phase ``intent``
(with the dispenser's cycle counter and load cell read just before and a 16-bit tag) *before*
the auger is told to start, and closed as ``done`` (grams from the load cell) or ``aborted``
after. ``controller.feed_outcome.reconcile()`` decides an open intent from the dispenser's own counters after a restart.
An outcome the counters cannot tell (a power cut reset them, another tag ran) is never freed:
the row becomes ``suspect``, its target still counted against the ration, until an operator
settles it with the grams (``settle_suspect``).

The schema is versioned with ``PRAGMA user_version``; ``MIGRATIONS[i]`` takes version i to i+1.
"""
from __future__ import annotations

import fcntl
import os
import re
import sqlite3
import threading
from pathlib import Path

from controller.cleaning.ledger import MIGRATION_5, CleanerRecords
from controller.errors import BadInput
from controller.feed_records import FeedRecords
from controller.ledger_config import MIGRATION_10
from controller.ledger_read import connect_read_only, why_unreadable
from controller.ledger_writes import LedgerUnwritable, LedgerWrites  # noqa: F401
from controller.override_requests import MIGRATION_8, RequestRecords
from controller.records import MIGRATION_4, Records
from controller.surveys.ledger import MIGRATION_6, MIGRATION_7, SurveyRecords

MIGRATIONS = [
    """
    CREATE TABLE demand (
        id       INTEGER PRIMARY KEY,
        tank     TEXT NOT NULL,
        t        REAL NOT NULL,
        rate_hz  REAL NOT NULL,
        outcome  TEXT NOT NULL DEFAULT 'open',   -- open | served | expired | ration_reached
        feed_id  TEXT
    );
    CREATE INDEX demand_tank_t ON demand (tank, t);
    CREATE TABLE feed (
        id           TEXT PRIMARY KEY,
        seq          INTEGER NOT NULL UNIQUE,
        tank         TEXT NOT NULL,
        date         TEXT NOT NULL,             -- farm day the grams count against
        t_intent     REAL NOT NULL,
        target_g     REAL NOT NULL,
        run_s        REAL NOT NULL,
        tag          INTEGER NOT NULL,
        cycles_before INTEGER NOT NULL,
        phase        TEXT NOT NULL,             -- intent | done | aborted
        grams        REAL,
        t_closed     REAL,
        note         TEXT,
        source       TEXT NOT NULL,             -- demand | operator
        demand_id    INTEGER
    );
    CREATE INDEX feed_tank_date ON feed (tank, date);
    CREATE INDEX feed_phase ON feed (phase);
    CREATE TABLE ration (
        tank      TEXT NOT NULL,
        date      TEXT NOT NULL,
        grams     REAL NOT NULL,
        pellet_mm REAL NOT NULL,
        source    TEXT NOT NULL,                -- config | survey | operator
        t         REAL NOT NULL,
        PRIMARY KEY (tank, date)
    );
    CREATE TABLE alarm (
        id       INTEGER PRIMARY KEY,
        source   TEXT NOT NULL,
        t        REAL NOT NULL,
        severity TEXT NOT NULL,
        text     TEXT NOT NULL,
        active   INTEGER NOT NULL
    );
    CREATE INDEX alarm_source ON alarm (source, id);
    """,
    # 1 -> 2: an alarm is a condition, (source, kind); rows of version 1 are each source's one kind
    """
    ALTER TABLE alarm ADD COLUMN kind TEXT NOT NULL DEFAULT 'general';
    DROP INDEX alarm_source;
    CREATE INDEX alarm_source_kind ON alarm (source, kind, id);
    """,
    # 2 -> 3: the load cell before each intent (a run the counters lost still shows as food gone),
    # who settled a suspect feed, and the dispenser counters last seen (counters going backwards
    # mean a power cut or a new PLC). Phase gains ``suspect``.
    """
    ALTER TABLE feed ADD COLUMN hopper_before REAL;
    ALTER TABLE feed ADD COLUMN settled_by TEXT;
    CREATE TABLE counters (
        device   TEXT PRIMARY KEY,
        cycles   INTEGER NOT NULL,
        total_g  REAL NOT NULL,
        t        REAL NOT NULL
    );
    """,
    # 3 -> 4: what operators do and are held to (controller.records): the audit of every override,
    # stock events, paused tanks, and each alarm's standing state (the ``alarm`` table stays its
    # history of changes)
    MIGRATION_4,
    # 4 -> 5: the pond cleaner's coverage map, path index and the path it followed
    # (controller.cleaning.ledger)
    MIGRATION_5,
    # 5 -> 6: weight surveys and every fish they counted (controller.surveys.ledger)
    MIGRATION_6,
    # 6 -> 7: the operators' survey requests still open (controller.surveys.ledger)
    MIGRATION_7,
    # 7 -> 8: the ids of overrides carried out, so one sent again is not done twice
    # (controller.override_requests)
    MIGRATION_8,
    # 8 -> 9: the farm time a controller's stop ended at (a restarted simulated farm carries on
    # from it: its clock ran on through the stop, past the ledger's last row)
    """
    CREATE TABLE farm_clock (
        id  INTEGER PRIMARY KEY CHECK (id = 1),
        t   REAL NOT NULL
    );
    """,
    # 9 -> 10: what the last start's config said of what the ledger's past is read by (stock,
    # species, the zone, the SCADA's layout): a change is logged at start (controller.ledger_config)
    MIGRATION_10,
    # 10 -> 11: an operator's feed is a demand of its own (source 'operator', its grams): accepted,
    # it outlives a stop and is served after the restart, as the fish's demands are
    """
    ALTER TABLE demand ADD COLUMN source TEXT NOT NULL DEFAULT 'demand';
    ALTER TABLE demand ADD COLUMN grams REAL;
    """,
]

# the oldest schema a reader (report, history, audit's store) takes as it is, without the controller
# migrating it first: 11 only added the demand table's source and grams, which no reader reads (a
# ledger archived at 10 could not be reported without writing to it). Raise it with a migration
# that changes what a reader reads.
READS_FROM = 10

# every farm time the ledger keeps (tests/controller/test_store.py checks no table's is missed)
LEDGER_TIMES = (("demand", "t"), ("feed", "t_intent"), ("feed", "t_closed"), ("ration", "t"), ("counters", "t"),
                ("alarm", "t"), ("alarm_state", "t"), ("alarm_state", "first_t"), ("alarm_state", "last_t"),
                ("alarm_state", "acked_t"), ("audit", "t"), ("stock_event", "t"), ("tank_pause", "t"),
                ("cleaner", "t"), ("cleaner_trace", "t"), ("survey", "t"), ("survey_asked", "t"),
                ("override_request", "t"), ("farm_clock", "t"), ("config_seen", "t"))


def ledger_time(path: str | Path) -> float | None:
    """The latest farm time the ledger at ``path`` records, in any of its tables (a night of
    surveys and cleaning writes no demand, feed or alarm: a restart carried on from before the
    night's survey rows); None when there is no ledger or nothing in it (a ledger that cannot be
    read is the Store's to refuse, later)."""
    if str(path) == ":memory:" or not Path(path).is_file():
        return None
    try:
        db, _ = connect_read_only(Path(path))         # in a directory this user may not write too
    except sqlite3.Error as exc:
        if getattr(exc, "sqlite_errorcode", 0) & 0xFF in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED):
            # it waited its while already: the Store's open would wait as long again (report and
            # history refused a locked ledger after 10-13 s, not 5), to say the same
            raise BadInput(str(path), None, f"cannot read the ledger: {exc}") from None
        return None
    latest = None
    try:
        for table, column in LEDGER_TIMES:
            try:
                t = db.execute(f"SELECT MAX({column}) FROM {table}").fetchone()[0]
            except sqlite3.Error:       # no such table yet (an old schema, not a ledger)
                continue
            if t is not None and (latest is None or t > latest):
                latest = float(t)
    finally:
        db.close()
    return latest


# How long a write waits for another process's write lock. A command line can wait (5 s); the
# controller writes on its event loop, where every wait holds up everything else: a sqlite3 shell
# left inside a transaction had each write wait 5 s, status take 10 s and an operator's e-stop
# answered "Timeout" (its latches set, its reply behind the loop). Locked past this, a write is the
# ledger unwritable (alarm, retried, nothing fed meanwhile), as a full disk is.
BUSY_MS = 5000
CONTROLLER_BUSY_MS = 200


class _Newer(Exception):
    """The file is not a ledger this program can use: a newer schema, another program's database,
    a table missing."""


def _refuse_foreign(db: sqlite3.Connection) -> None:
    """Another program's database (tables in it, no schema version of ours) is not a new ledger:
    the ledger's tables were added beside its own and the controller ran on it."""
    if db.execute("PRAGMA user_version").fetchone()[0] != 0:
        return
    tables = sorted(r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'"))
    if tables:
        raise _Newer(f"not a fishfarm ledger: another program's database (tables "
                     f"{', '.join(tables[:5])}{', ...' if len(tables) > 5 else ''})")


LEDGER_TABLES = frozenset(re.findall(r"CREATE TABLE (?:IF NOT EXISTS )?(\w+)", "\n".join(MIGRATIONS)))


class Store(LedgerWrites, FeedRecords, Records, CleanerRecords, SurveyRecords, RequestRecords):
    """One SQLite connection, used from the controller's event loop thread (plus a lock for
    the occasional call from another thread). Every write is its own committed transaction."""

    _claim: int | None = None         # the controller's hold on the ledger (``claim``): a locked file

    def __init__(self, path: str | Path, min_weighed: int = 1, busy_ms: int = BUSY_MS):
        self.path = Path(path)
        self.min_weighed = min_weighed
        self._lock = threading.RLock()
        self.db = None
        try:
            if str(path) != ":memory:":
                self.path.parent.mkdir(parents=True, exist_ok=True)
            self.db = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False)
            self.db.row_factory = sqlite3.Row
            _refuse_foreign(self.db)               # before WAL: another program's file is left as it was
            # WAL needs to write beside the file: an unwritable place fails here, at start, not mid-feed
            if self.db.execute("PRAGMA journal_mode=WAL").fetchone()[0] != "wal" and str(path) != ":memory:":
                raise sqlite3.OperationalError("cannot use write-ahead logging there")
            self.db.execute("PRAGMA synchronous=FULL")
            self.db.execute(f"PRAGMA busy_timeout={int(busy_ms)}")
            self._migrate()
        except _Newer as exc:
            self.close()
            raise BadInput("store.path", str(path), str(exc)) from None
        except (OSError, sqlite3.Error) as exc:
            self.close()
            if isinstance(exc, FileExistsError):
                why = f"{self.path.parent} is not a directory"
            else:
                why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise BadInput("store.path", str(path), f"cannot open the ledger: {why}") from None

    @classmethod
    def reader(cls, path: str | Path, min_weighed: int = 1) -> Store:
        """The ledger opened read-only (``fishfarm report``, ``history``): nothing written, no schema
        added to a file that is not a ledger. BadInput when it is not one of this program's schema."""
        self = cls.__new__(cls)
        self.path, self._lock, self.db = Path(path), threading.RLock(), None
        self.min_weighed = min_weighed
        try:
            version = self._open_read_only()
        except sqlite3.Error as exc:
            self.close()
            raise BadInput(str(path), None, f"cannot read the ledger: {exc}{why_unreadable(self.path)}") from None
        if not READS_FROM <= version <= len(MIGRATIONS):
            self.close()
            why = ("not a fishfarm ledger (no schema in it)" if version == 0 else
                   f"ledger schema {version}, this program reads {len(MIGRATIONS)}: "
                   + ("start the controller once to bring it up to date" if version < len(MIGRATIONS)
                      else "a newer program wrote it"))
            raise BadInput(str(path), None, why)
        return self

    def _open_read_only(self) -> int:
        self.db, version = connect_read_only(self.path)
        self.db.row_factory = sqlite3.Row
        return version

    # -- schema ---------------------------------------------------------------
    def _migrate(self) -> None:
        with self._lock:
            version = self.db.execute("PRAGMA user_version").fetchone()[0]
            if version > len(MIGRATIONS):
                raise _Newer(f"ledger schema {version}, this program reads {len(MIGRATIONS)}: "
                             "a newer program wrote it")
            for i in range(version, len(MIGRATIONS)):
                self.db.execute("BEGIN IMMEDIATE")
                try:
                    for statement in filter(str.strip, MIGRATIONS[i].split(";")):
                        self.db.execute(statement)
                    self.db.execute(f"PRAGMA user_version = {i + 1}")
                    self.db.execute("COMMIT")
                except BaseException:
                    # SQLite may have rolled back itself (a full disk): the cause is the one to tell,
                    # not "cannot rollback - no transaction is active"
                    if self.db.in_transaction:
                        self.db.execute("ROLLBACK")
                    raise
            tables = {r[0] for r in self.db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            missing = sorted(LEDGER_TABLES - tables)
            if missing:      # a ledger damaged by hand: refused here, not mid-run by the first write to it
                raise _Newer(f"ledger damaged: table{'s' if len(missing) > 1 else ''} {', '.join(missing)} missing")

    @property
    def schema_version(self) -> int:
        return self.db.execute("PRAGMA user_version").fetchone()[0]

    def claim(self) -> None:
        """Hold the ledger for this process's life: one controller per ledger. A second one settled
        the first's feed in flight as suspect at its start, and the first, resuming, served the
        same feed again. The hold is a lock on a file beside the ledger, which the kernel releases
        when the process ends however it ends (a SIGKILL, a power cut), so no stale lock outlives a
        controller. BadInput naming the holder when another process holds it."""
        if str(self.path) == ":memory:" or self._claim is not None:
            return
        # beside the file itself: a ledger reached through a symlink is the same ledger (two
        # controllers ran on one, each holding the lock beside its own name for it)
        real = self.path.resolve()
        lock = real.with_name(real.name + ".lock")
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise BadInput("store.path", str(self.path), f"cannot lock the ledger ({lock}): "
                                                         f"{exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.read(fd, 64).decode("ascii", "replace").strip() or "another process"
            os.close(fd)
            self.close()
            raise BadInput("store.path", str(self.path), f"another controller ({holder}) runs on this ledger: "
                                                         "one controller per ledger") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()}".encode())
        self._claim = fd

    def close(self) -> None:
        with self._lock:
            if self.db is not None:
                self.db.close()
                self.db = None
            if self._claim is not None:
                os.close(self._claim)        # the lock goes with it
                self._claim = None

    def mark_stopped(self, t: float) -> None:
        """The farm time a controller's stop ended at (``ledger_time`` reads it with the rest)."""
        self._write("INSERT OR REPLACE INTO farm_clock (id, t) VALUES (1, ?)", (t,))

    # -- demands --------------------------------------------------------------
    def add_demand(self, tank: str, t: float, rate_hz: float, source: str = "demand",
                   grams: float | None = None) -> int:
        """A demand to serve: the fish's (``rate_hz`` their contacts) or an operator's feed
        (``source`` 'operator', ``grams`` the portion asked, rate 0)."""
        return self._write("INSERT INTO demand (tank, t, rate_hz, source, grams) VALUES (?, ?, ?, ?, ?)",
                           (tank, t, rate_hz, source, grams)).lastrowid

    def close_demand(self, demand_id: int, outcome: str, feed_id: str | None = None) -> None:
        self._write("UPDATE demand SET outcome = ?, feed_id = ? WHERE id = ?", (outcome, feed_id, demand_id))

    def demand_outcome(self, demand_id: int) -> str | None:
        row = self.db.execute("SELECT outcome FROM demand WHERE id = ?", (demand_id,)).fetchone()
        return None if row is None else row["outcome"]

    def open_demands(self) -> list[sqlite3.Row]:
        return self.db.execute("SELECT * FROM demand WHERE outcome = 'open' ORDER BY t").fetchall()

    # -- rations --------------------------------------------------------------
    def set_ration(self, tank: str, date: str, grams: float, pellet_mm: float, source: str, t: float) -> None:
        self._write("INSERT INTO ration (tank, date, grams, pellet_mm, source, t) VALUES (?, ?, ?, ?, ?, ?) "
                    "ON CONFLICT (tank, date) DO UPDATE SET grams = excluded.grams, "
                    "pellet_mm = excluded.pellet_mm, source = excluded.source, t = excluded.t",
                    (tank, date, grams, pellet_mm, source, t))

    def ration(self, tank: str, date: str) -> sqlite3.Row | None:
        return self.db.execute("SELECT * FROM ration WHERE tank = ? AND date = ?", (tank, date)).fetchone()

    # -- alarms ---------------------------------------------------------------
    def add_alarm(self, source: str, t: float, severity: str, text: str, active: bool,
                  kind: str = "general") -> None:
        """One row per change of an alarm: raised, severity changed, cleared (controller.alarms)."""
        self._write("INSERT INTO alarm (source, kind, t, severity, text, active) VALUES (?, ?, ?, ?, ?, ?)",
                    (source, kind, t, severity, text, int(active)))

    def active_alarms(self) -> list[sqlite3.Row]:
        """The standing alarms: each (source, kind) whose latest row is active, oldest first."""
        return self.db.execute(
            "SELECT a.* FROM alarm a JOIN (SELECT source, kind, MAX(id) AS id FROM alarm GROUP BY source, kind) l "
            "ON a.id = l.id WHERE a.active = 1 ORDER BY a.t").fetchall()

    def alarms(self) -> list[sqlite3.Row]:
        return self.db.execute("SELECT * FROM alarm ORDER BY id").fetchall()
