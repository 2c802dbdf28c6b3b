"""The ledger opened read-only, by the commands that only read it (report, history, audit, the
cleaner's map) and the controller's history queryable."""
from __future__ import annotations

import os
import sqlite3
from pathlib import Path

READ_WAIT_S = 5.0         # how long a read waits for another process's exclusive lock (SQLite's own default)


def connect_read_only(path: Path) -> tuple[sqlite3.Connection, int]:
    """The ledger opened read-only, and its schema version; sqlite3.Error when it cannot be read.
    A ledger in WAL mode is read through its ``-shm`` index, which SQLite creates beside it: in a
    directory the reader may not write (the controller a service user, an operator reading) with no
    controller running — its ``-wal`` and ``-shm`` gone at its stop — the file alone is read as it
    stands (``immutable``); with a ``-wal`` beside it, it is refused (``why_unreadable`` says why)."""
    uri = Path(path).resolve().as_uri()
    for mode in ("mode=ro", "mode=ro&immutable=1"):
        db = sqlite3.connect(f"{uri}?{mode}", uri=True, isolation_level=None, check_same_thread=False,
                             timeout=READ_WAIT_S)
        try:
            return db, db.execute("PRAGMA user_version").fetchone()[0]
        except sqlite3.OperationalError as exc:
            db.close()
            code = getattr(exc, "sqlite_errorcode", 0) & 0xFF
            if "immutable" in mode or code not in (sqlite3.SQLITE_READONLY, sqlite3.SQLITE_CANTOPEN) or any(
                    Path(f"{path}{end}").exists() for end in ("-wal", "-shm")):
                raise
        except BaseException:
            db.close()
            raise
    raise AssertionError("unreachable")


def why_unreadable(path: Path) -> str:
    """What a read-only open's failure most likely means, where SQLite's words do not say it."""
    if Path(f"{path}-wal").exists() and not os.access(path.resolve().parent, os.W_OK):
        return (f" (a write-ahead log is beside it and {path.resolve().parent} is not writable for this user: "
                "read it as the controller's user, or once the controller has stopped cleanly)")
    return ""
