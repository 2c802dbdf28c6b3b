"""An override sent again is done once: a payload may carry ``request``, an id its sender chose
(a UUID, say). The first accepted command under an id is remembered in the ledger with its reply;
the same id again gets that reply, marked ``"repeat": true``, and nothing is done again — so a
client whose reply was lost (a timeout, a dropped link) can send its mortality, feed or transfer
again without booking it twice. A repeat that arrives while the first is still being carried out
waits for the first's reply. Only accepted commands are remembered: a refusal ("the controller is
starting", "more than the fish in the tank") may be sent again under its id and is tried anew. An
id already given to a command with other values (``count`` 6 where it was 5) is refused: answered
"ok" as a repeat, the six dead fish were never booked and their sender was told they were.

The command and its remembered reply are two writes: a controller killed between them (no await
lies between, so only a kill does it) carries the command out and forgets the id. A command that
needs no ledger (a reset, an acknowledge) is carried out while the ledger cannot be written; its
reply is then "ok" with a ``note`` that the id is not remembered (it was "cannot be written, try
again", of a reset done).
"""
from __future__ import annotations

import asyncio
import hashlib
import json
import re
import sqlite3
import threading
from collections.abc import Awaitable, Callable

from controller.override_models import REQUEST_PATTERN

MIGRATION_8 = """
    CREATE TABLE override_request (
        request   TEXT PRIMARY KEY,
        command   TEXT NOT NULL,
        t         REAL NOT NULL,
        reply     TEXT NOT NULL
    );
"""
"""7 -> 8: the ids of overrides carried out, with their replies."""

def request_id(payload: object) -> str | None:
    """The payload's ``request`` when it is an id the command's model takes (the same pattern);
    its faults are the model's to say."""
    request = payload.get("request") if isinstance(payload, dict) else None
    return request if isinstance(request, str) and re.fullmatch(REQUEST_PATTERN, request) else None


class RequestRecords:
    """A mixin of ``controller.store.Store``: the remembered requests."""
    db: sqlite3.Connection
    _lock: threading.RLock

    def remember_request(self, request: str, command: str, t: float, reply: dict) -> None:
        self._write("INSERT OR IGNORE INTO override_request (request, command, t, reply) VALUES (?, ?, ?, ?)",
                    (request, command, t, json.dumps(reply)))

    def request_done(self, request: str) -> tuple[str, dict] | None:
        row = self.db.execute("SELECT command, reply FROM override_request WHERE request = ?",
                              (request,)).fetchone()
        return None if row is None else (row["command"], json.loads(row["reply"]))


ASKED = "_asked"      # the remembered reply's key for what was asked (a digest), never sent on


def asked(payload: object) -> str:
    """A digest of what a payload asks, its ``request`` id aside."""
    rest = {k: v for k, v in payload.items() if k != "request"} if isinstance(payload, dict) else payload
    return hashlib.sha256(json.dumps(rest, sort_keys=True, default=str).encode()).hexdigest()[:32]


class Once:
    """Carries out each request id once (see the module's text)."""

    def __init__(self, ledger: Callable[[], RequestRecords], refused: type[Exception],
                 unwritable: type[Exception] = OSError):
        self.ledger, self.refused, self.unwritable = ledger, refused, unwritable
        self._running: dict[str, asyncio.Future] = {}

    async def run(self, command: str, request: str | None, t: float,
                  act: Callable[[], Awaitable[dict]], payload: object = None) -> dict:
        if request is None:
            return await act()
        digest = asked(payload)
        running = self._running.get(request)
        if running is not None:
            first_command, reply = await asyncio.shield(running)
            return self._again(command, digest, first_command, reply)
        done = self.ledger().request_done(request)
        if done is not None:
            return self._again(command, digest, *done)
        future = asyncio.get_running_loop().create_future()
        self._running[request] = future
        try:
            reply = await act()
            if reply.get("ok") is True:
                try:
                    self.ledger().remember_request(request, command, t, {**reply, ASKED: digest})
                except self.unwritable as exc:
                    # done all the same (a reset, an acknowledge: nothing of theirs is in the
                    # ledger): said so, never "cannot be written, try again" of a thing done
                    reply = {**reply, "note": f"done, but the ledger cannot be written ({exc}): request "
                                              f"{request} is not remembered; sent again, it is done again"}
            future.set_result((command, {**reply, ASKED: digest}))
            return reply
        except BaseException as exc:
            future.set_exception(exc)
            future.exception()      # retrieved: a lone first raising is not "never retrieved"
            raise
        finally:
            del self._running[request]

    def _again(self, command: str, digest: str, first_command: str, reply: dict) -> dict:
        if first_command != command:
            raise self.refused(f"request: already the id of a {first_command} override")
        first = reply.get(ASKED)              # none in an id remembered before it was kept
        reply = {k: v for k, v in reply.items() if k != ASKED}
        if first is not None and first != digest:
            raise self.refused(f"request: already the id of a {command} override with other values "
                               "(a new request needs a new id)")
        if reply.get("ok") is not True:        # the first was refused while this copy waited
            return reply
        return {**reply, "repeat": True}
