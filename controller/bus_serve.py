"""The bus's serving side: queryables and overrides answered from the controller's loop.

A query arrives on a Zenoh thread. ``_on_query`` never blocks it and never lets it raise: an
``urgent`` action (estop) runs right there, first; the payload is parsed; the handler is scheduled
onto the loop, and its reply is sent from the loop when it finishes. Every concrete query gets a
reply; a wildcard get is dropped unanswered (it must not fire every command).
"""
from __future__ import annotations

import asyncio
import contextlib
import functools
import inspect
import json
import logging
import math
import re
from collections.abc import Awaitable, Callable, Iterable, Mapping

import zenoh

from controller.identity import BY, USER, user_of
from controller.payload import NotAnObject, Unread, parse_object
from controller.text import printable
from controller.zenoh_config import _one_line

log = logging.getLogger("fishfarm.bus")

Handler = Callable[..., Awaitable[dict]]
"""A queryable's handler: request payload (a JSON object) in, reply (a JSON object) out. An
override handler that takes a ``user`` keyword gets the authenticated user name (controller.identity)
or None: ``await handler(payload, user=...)``; one that does not is called ``handler(payload)``."""
_CHUNK = re.compile(r"^[^/*$#?]+$")  # one concrete key chunk: no wildcard, no selector syntax
MAX_REQUEST_BYTES = 64 * 1024
"""The largest request payload read: ours are a few hundred bytes. A bigger one is refused unread,
as not readable: parsing 50 MB of JSON held the GIL for a second on a Zenoh thread, and the e-stop
thread beside it waited (2.45 s to the latches, 10 such overrides in flight), and a client chose
how much memory the controller kept (2.6 GB with 40 in flight). A lenient command's (the e-stop's)
is read whatever its size: it has acted before, and its audit names who sent it."""


def encode(payload: dict) -> bytes:
    """JSON, UTF-8. NaN/inf are not JSON and other clients would choke on them: a figure that is
    one goes as null, logged once by where it is (one tank's NaN figure had every status reply
    refused, for the whole farm)."""
    if not isinstance(payload, dict):
        raise TypeError(f"bus payloads are JSON objects, not {type(payload).__name__}")
    try:
        return json.dumps(payload, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()
    except ValueError as exc:
        if "Out of range float" not in str(exc):
            raise
    where: list[str] = []
    clean = _finite(payload, "", where)
    for path in where:
        if path not in _NOT_FINITE_SEEN:
            _NOT_FINITE_SEEN.add(path)
            log.warning("a figure that is not a number sent as null: %s", path or "(the payload)")
    return json.dumps(clean, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()


_NOT_FINITE_SEEN: set[str] = set()


def _finite(value, path: str, where: list[str]):
    """``value`` with every NaN or infinite float as None; their paths appended to ``where``."""
    if isinstance(value, float) and not math.isfinite(value):
        where.append(path)
        return None
    if isinstance(value, dict):
        return {k: _finite(v, f"{path}.{k}" if path else str(k), where) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v, f"{path}[{i}]", where) for i, v in enumerate(value)]
    return value


class Prepared(dict):
    """A reply encoded once (``data``): one shared by many queries goes out as is, not encoded again
    for each (a flood of ``status`` queries, each encoding the whole farm on the loop, had the
    Modbus e-stop wait seconds behind them)."""

    def __init__(self, answer: dict):
        super().__init__(answer)
        self.data = encode(answer)


def _request(query: zenoh.Query, lenient: bool = False) -> dict:
    """A query's payload, as ``decode`` reads it, refused unread when over MAX_REQUEST_BYTES
    (unless ``lenient``)."""
    data = query.payload
    if not lenient and data is not None and len(data) > MAX_REQUEST_BYTES:
        raise ValueError(f"payload of {len(data):,} bytes: a request is at most {MAX_REQUEST_BYTES:,}")
    return decode(data)


def decode(data: zenoh.ZBytes | bytes | None) -> dict:
    """A payload as a dict; no payload at all is ``{}``. Raises ValueError saying what is wrong:
    not UTF-8, not JSON, not an object, nested too deep, a key given twice (controller.payload)."""
    return parse_object(bytes(data.to_bytes() if isinstance(data, zenoh.ZBytes) else data or b""))


class RefusedOnWire(LookupError):
    """A query refused before any handler (an unknown command, a bad user key): ``notify(payload)``
    tells the audit, with the payload as received (a ``Received`` when JSON but no object, None
    when unreadable)."""

    def __init__(self, error: str, notify):
        super().__init__(error)
        self.notify = notify


class Serving:
    """Mixin of ``Bus``: needs ``session``, ``key()``, ``_suffix()``, ``identified``,
    ``_handler_loop()`` and ``_keep()``."""

    def queryable(self, suffix: str, handler: Handler, *, lenient: bool = False, selector: bool = False,
                  ready: Callable[[], dict | None] | None = None) -> None:
        """Answer gets on ``farm/{site}/{suffix}`` with ``await handler(payload)``.
        A payload that is not a JSON object is refused (``{"ok": false, "error": ...}``) unless
        ``lenient``, when the handler gets ``{}``. A handler exception is such a refusal too.
        ``selector``: ``suffix`` may hold wildcards, and the handler is called
        ``handler(payload, key=..., params=...)`` with the concrete key's suffix and the selector's
        parameters (``...?since=2026-06-01;until=...``, strings). ``ready()``, called on the Zenoh
        thread, may give an answer at hand (a cached snapshot): it goes out at once, the loop not
        involved; None: the handler answers as ever."""
        if not selector:
            wrapped = _with_user(handler)
            # a concrete key (status): a wildcard get (farm/*/status, a client finding the sites) is
            # answered on it, as no command is fired by it (it went unanswered: an outside tester)
            wild = self.key(suffix) if _concrete(self.key(suffix)) else None
            self._serve(suffix, lambda _key: (wrapped, lenient, None, None, None), ready, wild)
            return

        def resolve(key: str):
            async def bound(payload: dict, *, user=None, params=None):
                return await handler(payload, key=key, params=params or {})
            return bound, lenient, None, None, None, True
        self._serve(suffix, resolve)

    def overrides(self, commands: Mapping[str, Handler], *, lenient: Iterable[str] = ("estop",),
                  urgent: Mapping[str, Callable[[], None]] | None = None,
                  refused: Callable[[str, str, str | None], None] | None = None) -> None:
        """Serve ``farm/{site}/override/*`` and ``farm/{site}/override/*/by/*``: dispatch on the
        command name; an unknown command, and any other key under ``override``, is refused.
        Commands in ``lenient`` (estop) are never refused for their payload; those in ``urgent``
        first call their function on the Zenoh thread, before anything else. A handler taking a
        ``user`` keyword gets the user of a ``.../by/USER`` key when this session enforces the ACL
        (``identified``), else None.
        ``refused(command, error, user)`` hears, on the loop, of every query refused here before a
        handler saw it (unknown command, unreadable payload): the audit keeps those too."""
        forgiving = set(lenient)
        table = {name: _with_user(handler) for name, handler in commands.items()}
        now = dict(urgent or {})
        loop = self._handler_loop()

        def tell(command: str, error: str, user: str | None = None, payload=None) -> None:
            if refused is not None:
                with contextlib.suppress(RuntimeError):     # the loop is closed: the process is ending
                    loop.call_soon_threadsafe(refused, command, error, user, payload)

        def resolve(suffix: str):
            chunks = suffix.split("/")
            if not (len(chunks) == 2 or (len(chunks) == 4 and chunks[2] == BY)):
                # override/feed/now, a bare override: one queryable answers them all, as it answers
                # an unknown command, rather than leaving the asker to time out
                error = (f"{printable(self.key(suffix), 160)!r}: not a command's key; send to "
                         f"{self.key('override')}/COMMAND (or .../COMMAND/{BY}/USER)")
                raise RefusedOnWire(error, lambda payload: tell(suffix, error, None, payload))
            base, user = user_of(suffix)
            command = base.split("/", 1)[1]
            if user is not None and not USER.match(user):
                error = f"user {user!r}: letters, digits, _ . - only"
                raise RefusedOnWire(error, lambda payload: tell(command, error, None, payload))
            if command not in table:
                error = f"unknown command {printable(command, 64)!r}; known: {', '.join(sorted(table))}"
                who = user if self.identified else None
                raise RefusedOnWire(error, lambda payload: tell(command, error, who, payload))
            user = user if self.identified else None
            return (table[command], command in forgiving, now.get(command), user,
                    lambda error, payload=None: tell(command, error, user, payload))
        self._serve("override/**", resolve)

    def _serve(self, suffix: str, resolve, ready=None, wild: str | None = None) -> None:
        loop = self._handler_loop()
        self._keep(self.session.declare_queryable(
            self.key(suffix), lambda query: self._on_query(query, resolve, loop, ready, wild)))

    def _on_query(self, query: zenoh.Query, resolve, loop: asyncio.AbstractEventLoop, ready=None,
                  wild: str | None = None) -> None:
        """On a Zenoh thread: act (urgent), parse, then hand the work to the loop. Never blocks,
        never raises, and every concrete query gets a reply (a wildcard one too where ``wild``,
        the queryable's own concrete key, answers it)."""
        key = str(query.key_expr)
        if not _concrete(key):
            if wild is None:
                # a wildcard get (override/**) must not fire every command: nobody answers it
                query.drop()
                return
            key, query = wild, _OnKey(query, wild)
        try:
            answer = ready() if ready is not None else None
            if answer is not None:
                return self._reply(query, answer)
            self._dispatch(query, key, resolve, loop)
        except BaseException as exc:  # noqa: BLE001 - a Zenoh thread must not die, the querier must hear
            self._reply(query, {"ok": False, "error": f"internal error: {type(exc).__name__}"})
            if not isinstance(exc, Exception):
                raise

    def _dispatch(self, query: zenoh.Query, key: str, resolve, loop) -> None:
        try:
            handler, lenient, urgent, user, refused, *selector = resolve(self._suffix(key))
        except LookupError as exc:
            if isinstance(exc, RefusedOnWire):       # audited with what the payload claims, if readable
                try:
                    payload = _request(query)
                except Exception as bad:  # noqa: BLE001 - whatever a hostile payload raises: kept as none
                    payload = _received(bad)
                exc.notify(payload)
            return self._reply(query, {"ok": False, "error": str(exc)})
        if selector:
            keys = [part.split("=", 1)[0] for part in str(query.parameters).split(";") if part]
            twice = sorted({k for k in keys if keys.count(k) > 1})
            if twice:                 # Zenoh keeps one of them: which one was meant is the asker's to say
                return self._reply(query, {"ok": False, "error": f"{printable(twice[0], 64)}: given twice in the "
                                                                 "selector"})
            params = {k: v for k, v in dict(query.parameters).items() if k != "_time"}
            handler = functools.partial(handler, params=params)
        acted = False
        if urgent is not None:
            try:
                urgent()
                acted = True
            except Exception:
                log.exception("urgent action for %s failed", key)
        try:
            payload = _request(query, lenient)
        except Exception as exc:  # noqa: BLE001 - ValueError, or whatever a hostile payload raises
            if not lenient:
                error = str(exc) if isinstance(exc, ValueError) else f"unreadable payload ({type(exc).__name__})"
                if refused is not None:
                    refused(error, _received(exc))
                return self._reply(query, {"ok": False, "error": error})
            payload = Unread(_received(exc))
        try:
            future = asyncio.run_coroutine_threadsafe(_answer(handler, payload, key, user), loop)
        except RuntimeError:  # the loop is closed: the controller is stopping
            error = "controller is shutting down" + (" (acted on already)" if acted else "")
            return self._reply(query, {"ok": acted, "error": error} if not acted else {"ok": True, "note": error})
        future.add_done_callback(lambda f: self._reply(query, _outcome(f)))

    def _reply(self, query: zenoh.Query, answer: dict) -> None:
        try:
            try:
                data = answer.data if isinstance(answer, Prepared) else encode(answer)
            except (TypeError, ValueError) as exc:
                data = encode({"ok": False, "error": f"reply is not JSON-serialisable: {exc}"})
            query.reply(query.key_expr, data, encoding=zenoh.Encoding.APPLICATION_JSON)
        except zenoh.ZError as exc:  # session closed or querier gone: nobody to tell
            log.debug("reply to %s lost: %s", query.key_expr, _one_line(exc))
        finally:
            query.drop()  # finalises the query: the querier stops waiting now, not at its timeout


def _concrete(key: str) -> bool:
    return all(_CHUNK.match(c) for c in key.split("/"))


class _OnKey:
    """A query answered on ``key`` (the queryable's own) rather than on its wildcard expression."""

    def __init__(self, query: zenoh.Query, key: str):
        self._query, self.key_expr = query, zenoh.KeyExpr(key)

    def __getattr__(self, name: str):
        return getattr(self._query, name)


def _received(exc: BaseException):
    """What the audit keeps of a payload that did not decode: JSON that is no object, as sent;
    else none (it was not readable)."""
    return exc.received if isinstance(exc, NotAnObject) else None


def _with_user(handler: Handler) -> Handler:
    """``handler`` itself if it takes a ``user`` keyword; else a wrapper dropping ``user``, so the
    handlers written before identities (``async def h(payload)``) keep working."""
    try:
        params = inspect.signature(handler).parameters.values()
    except (TypeError, ValueError):  # a builtin or C callable: assume the old form
        params = ()
    if any(p.name == "user" and p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD) or p.kind == p.VAR_KEYWORD
           for p in params):
        return handler

    async def payload_only(payload, *, user=None):
        return await handler(payload)
    return payload_only


async def _answer(handler: Handler, payload: dict, key: str, user: str | None = None) -> dict:
    """Run one handler; whatever goes wrong becomes a refusal the operator can read."""
    try:
        answer = await handler(payload, user=user)
    except Exception as exc:
        log.exception("handler for %s failed", key)
        return {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
    if not isinstance(answer, dict):
        return {"ok": False, "error": f"handler returned {type(answer).__name__}, not a JSON object"}
    return answer


def _outcome(future) -> dict:
    if future.cancelled():
        return {"ok": False, "error": "controller is shutting down"}
    exc = future.exception()  # only BaseException gets here (_answer catches the rest)
    return {"ok": False, "error": f"handler aborted: {exc!r}"} if exc else future.result()
