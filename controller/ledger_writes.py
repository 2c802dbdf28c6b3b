"""How the ledger is written, and what happens when it cannot be: a full disk, a read-only
remount, an I/O error. A base of ``controller.store.Store``.

Every write goes through ``_write`` (one statement, its own commit) or ``transaction()`` (several
statements, one commit). A write that fails for the file's sake raises ``LedgerUnwritable`` (an
``sqlite3.OperationalError``, so existing handlers still catch it) and marks the ledger unwritable:
``unwritable`` holds the cause until a later write succeeds. The loss and the recovery are each
logged once, here, not as a traceback by every caller (the controller alarms on it: ``ledger``
kind ``unwritable``). A write the ledger refuses on its own terms (a constraint) is the caller's
fault, not the file's: it raises as before and changes nothing here.
"""
from __future__ import annotations

import contextlib
import logging
import os
import sqlite3
import threading
import time
from collections.abc import Iterator

log = logging.getLogger("fishfarm.store")


class LedgerUnwritable(sqlite3.OperationalError):
    """The ledger's file cannot take a write now (the message says why: SQLite's words)."""


class LedgerWrites:
    db: sqlite3.Connection | None
    _lock: threading.RLock
    unwritable: str | None = None         # the cause, while the last write failed for the file's sake
    unwritable_since: float | None = None  # time.monotonic() of the first failure

    def _write(self, sql: str, args=()) -> sqlite3.Cursor:
        with self._lock:
            try:
                cur = self.db.execute(sql, args)
            except sqlite3.Error as exc:
                raise self._failed(exc) from exc
            self._wrote()
            return cur

    @contextlib.contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """``BEGIN IMMEDIATE`` … ``COMMIT``, rolled back on any exception. SQLite may have rolled
        back itself (a full disk): then the cause is the one to tell, not "cannot rollback"."""
        with self._lock:
            try:
                self.db.execute("BEGIN IMMEDIATE")
                yield self.db
                self.db.execute("COMMIT")
            except BaseException as exc:
                if self.db is not None and self.db.in_transaction:
                    with contextlib.suppress(sqlite3.Error):
                        self.db.execute("ROLLBACK")
                if isinstance(exc, sqlite3.Error):
                    raise self._failed(exc) from exc
                raise
            self._wrote()

    def _failed(self, exc: sqlite3.Error) -> sqlite3.Error:
        """What to raise for ``exc``: LedgerUnwritable when the file is at fault (logged once)."""
        if isinstance(exc, LedgerUnwritable) or not _the_files_fault(exc):
            return exc
        cause = (str(exc) or type(exc).__name__) + _size_limit_reached(getattr(self, "path", None))
        if self.unwritable is None:
            self.unwritable, self.unwritable_since = cause, time.monotonic()
            log.error("ledger: cannot write: %s; nothing is fed until it can be written", cause)
        return LedgerUnwritable(cause)

    def _wrote(self) -> None:
        if self.unwritable is not None:
            took = time.monotonic() - (self.unwritable_since or time.monotonic())
            log.warning("ledger: written again, after %.0f s unwritable (%s)", took, self.unwritable)
            self.unwritable = self.unwritable_since = None


def _size_limit_reached(path) -> str:
    """Why a write failed, where SQLite says only "disk I/O error": the process's file-size limit
    (``ulimit -f``; Python ignores its SIGXFSZ, so the write just fails), when a ledger file is at it."""
    import resource
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if path is None or limit == resource.RLIM_INFINITY:
        return ""
    sizes = [os.path.getsize(f"{path}{end}") for end in ("", "-wal") if os.path.exists(f"{path}{end}")]
    if sizes and max(sizes) >= limit - 65_536:
        return f" (the file-size limit of this process, ulimit -f: {limit} bytes, reached)"
    return ""


def _the_files_fault(exc: sqlite3.Error) -> bool:
    """Full, read-only, I/O, locked past the busy timeout, corrupt: not a statement's fault."""
    if isinstance(exc, sqlite3.IntegrityError | sqlite3.ProgrammingError | sqlite3.InterfaceError):
        return False
    return getattr(exc, "sqlite_errorcode", 0) & 0xFF in _FILE_CODES     # extended codes: IOERR_WRITE...


_FILE_CODES = {sqlite3.SQLITE_FULL, sqlite3.SQLITE_READONLY, sqlite3.SQLITE_IOERR, sqlite3.SQLITE_BUSY,
               sqlite3.SQLITE_LOCKED, sqlite3.SQLITE_CORRUPT, sqlite3.SQLITE_CANTOPEN, sqlite3.SQLITE_NOTADB,
               sqlite3.SQLITE_PROTOCOL}
