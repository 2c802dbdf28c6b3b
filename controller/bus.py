"""The farm's Zenoh bus: one session per process, JSON payloads under ``farm/{site}/``.

Zenoh runs its callbacks on its own threads; the controller's logic runs on one asyncio loop.
Every handler here is an ``async def`` scheduled onto that loop with
``asyncio.run_coroutine_threadsafe``, so a slow handler never holds a Zenoh thread, and the
reply is sent from the loop when the handler finishes. An ``urgent`` override (estop) also runs
a plain function on the Zenoh thread itself, first, before the payload is even parsed: it acts
whatever the payload and however busy the loop is. Every query gets a reply.

Overrides are served on ``override/{command}`` (the contract key) and on
``override/{command}/by/{user}``, a key the deployment's ACL lets only that user query
(controller/identity.py): a handler taking a ``user`` keyword is told that user, or None.

Reliable publishes (``CongestionControl.BLOCK``) block while a subscriber's link is full, so
they never run on the caller's thread: a publisher thread sends them in order (order kept for
every key). ``close()`` gives it ``DRAIN_S`` to finish.

Facts that shaped this module (eclipse-zenoh 1.10.2, see DESIGN.md):
- multicast scouting reaches beyond loopback: it is forced off whatever the config says;
- the default congestion control drops under load: ``reliable=True`` publishes with BLOCK;
- a wrong password does not make a *peer* ``zenoh.open()`` raise (a client's does): it returns
  a session with nobody in it, so clients check connectivity explicitly;
- sessions with callback subscribers keep non-daemon threads alive: always ``close()``.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import queue
import threading
import time
from collections.abc import Awaitable, Callable

import zenoh

from controller.bus_serve import _CHUNK, Handler, Serving, _with_user, decode, encode
from controller.config import BusConfig
from controller.errors import BadInput
from controller.identity import identities_bound
from controller.zenoh_config import _one_line, _why_unreachable, client_config, session_config

__all__ = ["Bus", "BusUnreachable", "Handler", "_with_user", "client_config", "decode", "encode",
           "session_config"]

log = logging.getLogger("fishfarm.bus")

Listener = Callable[[str, dict], Awaitable[None]]
"""A subscriber's handler: key suffix after ``farm/{site}/`` and the payload."""

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
DRAIN_S = 2.0            # wall seconds close() waits for queued reliable publishes
QUEUE_MAX = 100_000      # reliable publishes waiting; past that they are dropped (and logged once)


class BusUnreachable(Exception):
    """A client could not reach (or was not admitted to) the Zenoh network. ``str()`` is one line."""


# ---------------------------------------------------------------- the bus

class Bus(Serving):
    """One Zenoh session for the process, speaking the key space of DESIGN.md.

    ``loop`` is the asyncio loop handlers run on; by default the loop running when
    ``queryable``/``subscribe``/``overrides`` is called.
    """

    def __init__(self, cfg: BusConfig, site: str = "demo", *, loop: asyncio.AbstractEventLoop | None = None):
        zc = session_config(cfg)
        try:
            session = zenoh.open(zc)
        except zenoh.ZError as exc:
            why = f"cannot open Zenoh session: {_one_line(exc)}"
            raise BadInput(cfg.config or "[bus]", None, why) from None
        self._start(session, zc, site, loop)
        # this session enforces the ACL bind_identities extended: a query on .../by/USER came from USER
        self.identified = identities_bound(json.loads(zc.get_json("access_control")))

    @classmethod
    def client(cls, connect: str = DEFAULT_CONNECT, *, site: str = "demo", user: str | None = None,
               password: str | None = None, timeout_s: float = 2.0, mode: str = "client",
               loop: asyncio.AbstractEventLoop | None = None, ca: str | None = None) -> Bus:
        """A tool's bus (CLI, tests): connected to ``connect`` and checked to have reached somebody
        within ``timeout_s``; otherwise BusUnreachable saying whether nobody answered or the
        session was refused (authentication)."""
        zc = client_config(connect, user, password, mode=mode, timeout_s=timeout_s, ca=ca)
        try:
            session = zenoh.open(zc)
        except zenoh.ZError as exc:
            raise BusUnreachable(_why_unreachable(connect, user, _one_line(exc))) from None
        bus = cls.__new__(cls)
        bus._start(session, zc, site, loop)
        if not bus.wait_connected(timeout_s):
            bus.close()
            raise BusUnreachable(_why_unreachable(connect, user, f"nobody answered within {timeout_s:g} s"))
        return bus

    def _start(self, session: zenoh.Session, zc: zenoh.Config, site: str, loop) -> None:
        if not _CHUNK.match(site):
            raise ValueError(f"site {site!r} is not a plain key chunk")
        self.session, self.zconfig, self.site = session, zc, site
        self.identified = False
        self.prefix = f"farm/{site}/"
        self._loop = loop
        self._lock = threading.Lock()
        self._publishers: dict[tuple[str, bool], zenoh.Publisher] = {}
        self._declared: list = []  # subscribers and queryables, undeclared on close
        self._closed = False
        self._outbox: queue.Queue = queue.Queue(QUEUE_MAX)
        self._overflowed = False
        self._sender = threading.Thread(target=self._send_reliable, name="bus-publisher", daemon=True)
        self._sender.start()

    # ------------------------------------------------------------ keys and peers

    def key(self, suffix: str) -> str:
        return self.prefix + suffix.strip("/")

    def _suffix(self, key: str) -> str:
        return key[len(self.prefix):] if key.startswith(self.prefix) else key

    def neighbours(self) -> list[str]:
        """Zenoh ids of the routers and peers this session has a transport to."""
        info = self.session.info
        return [str(z) for z in (*info.routers_zid(), *info.peers_zid())]

    def wait_connected(self, timeout_s: float) -> bool:
        """True as soon as some router or peer is connected, False after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while not self.neighbours():
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True

    # ------------------------------------------------------------ publish

    def publish(self, suffix: str, payload: dict, *, reliable: bool = False) -> None:
        """Put ``payload`` on ``farm/{site}/{suffix}``. ``reliable``: ledger (feed) and alarm
        events, which must not be dropped under load: queued for the publisher thread, which
        blocks while the link's queue is full; the caller never does."""
        publisher, data = self._publisher(suffix, reliable), encode(payload)
        if not reliable:
            publisher.put(data)
            return
        try:
            self._outbox.put_nowait((publisher, data))
        except queue.Full:
            if not self._overflowed:
                self._overflowed = True
                log.error("reliable publishes back up (a subscriber stalls?): dropping %s and later ones "
                          "while the queue is full", suffix)

    def flush(self, timeout_s: float = DRAIN_S) -> bool:
        """Wait until every queued reliable publish has been handed to Zenoh; False on timeout."""
        done = threading.Event()
        try:
            self._outbox.put((None, done), timeout=timeout_s)
        except queue.Full:
            return False
        return done.wait(timeout_s)

    def _send_reliable(self) -> None:
        while True:
            publisher, data = self._outbox.get()
            if publisher is None:
                if data is None:
                    return                  # close(): everything before it was sent
                data.set()                  # a flush() marker
                continue
            try:
                publisher.put(data)
                self._overflowed = False
            except zenoh.ZError as exc:     # undeclared under us (closing): nobody to tell
                log.debug("reliable publish lost: %s", _one_line(exc))

    def matched(self, suffix: str, *, reliable: bool = False) -> bool:
        """Whether some subscriber, here or remote, matches ``farm/{site}/{suffix}`` now."""
        return self._publisher(suffix, reliable).matching_status

    def _publisher(self, suffix: str, reliable: bool) -> zenoh.Publisher:
        with self._lock:
            if self._closed:
                raise RuntimeError("bus is closed")
            pub = self._publishers.get((suffix, reliable))
            if pub is None:
                qos = dict(congestion_control=zenoh.CongestionControl.BLOCK,
                           reliability=zenoh.Reliability.RELIABLE, express=True) if reliable else {}
                try:
                    pub = self.session.declare_publisher(
                        self.key(suffix), encoding=zenoh.Encoding.APPLICATION_JSON, **qos)
                except zenoh.ZError as exc:
                    raise ValueError(f"bad key suffix {suffix!r}: {_one_line(exc)}") from None
                self._publishers[(suffix, reliable)] = pub
            return pub

    # ------------------------------------------------------------ subscribers

    def subscribe(self, suffix: str, listener: Listener) -> None:
        """``await listener(key_suffix, payload)`` on the loop for every sample on
        ``farm/{site}/{suffix}`` (wildcards allowed). Malformed payloads are logged and skipped."""
        loop = self._handler_loop()
        self._keep(self.session.declare_subscriber(
            self.key(suffix), lambda sample: self._on_sample(sample, listener, loop)))

    def _on_sample(self, sample: zenoh.Sample, listener: Listener, loop) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        key = str(sample.key_expr)
        try:
            payload = decode(sample.payload)
        except ValueError as exc:
            log.warning("%s: %s (sample skipped)", key, exc)
            return
        with contextlib.suppress(RuntimeError):  # RuntimeError: the loop closed while stopping
            asyncio.run_coroutine_threadsafe(_deliver(listener, self._suffix(key), payload), loop)

    # ------------------------------------------------------------ queries (tools)

    def query(self, suffix: str, payload: dict | None = None, *, timeout_s: float = 2.0) -> list[dict]:
        """Blocking get on ``farm/{site}/{suffix}``: every reply as a dict (an unreadable one becomes
        ``{"ok": false, "error": ...}``). For tools and threads, not the loop. Zenoh's own error
        replies are no answer and are left out: our servers refuse with a JSON reply, never an error
        one, and Zenoh says "Timeout" so when the answer did not come back in time — read as the
        controller's refusal, an override it had carried out was reported refused (and sent again
        without its id, done twice), the e-stop it had latched "not done"."""
        data = encode(payload) if payload is not None else None
        replies = []
        for reply in self.session.get(self.key(suffix), payload=data, timeout=timeout_s,
                                      encoding=zenoh.Encoding.APPLICATION_JSON):
            if reply.ok is None:
                log.debug("farm/%s/%s: Zenoh's error reply %r taken as no answer", self.site, suffix,
                          reply.err.payload.to_bytes().decode("utf-8", "ignore"))
                continue
            try:
                replies.append(decode(reply.ok.payload))
            except ValueError as exc:
                replies.append({"ok": False, "error": f"unreadable reply: {exc}"})
        return replies

    # ------------------------------------------------------------ lifetime

    def _handler_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            try:
                self._loop = asyncio.get_running_loop()
            except RuntimeError:
                raise RuntimeError("Bus handlers need an asyncio loop: call from the loop or pass "
                                   "Bus(..., loop=...)") from None
        return self._loop

    def _keep(self, entity) -> None:
        with self._lock:
            if self._closed:
                entity.undeclare()
                raise RuntimeError("bus is closed")
            self._declared.append(entity)

    def close(self) -> None:
        """Undeclare everything and close the session. Safe to call twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        try:       # queued reliable publishes go out first, for DRAIN_S at most
            self._outbox.put((None, None), timeout=DRAIN_S)
        except queue.Full:
            pass
        self._sender.join(DRAIN_S)
        with self._lock:
            declared = [*self._publishers.values(), *self._declared]
            self._publishers.clear()
            self._declared.clear()
        for entity in declared:
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()
        self.session.close()

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


async def _deliver(listener: Listener, suffix: str, payload: dict) -> None:
    try:
        await listener(suffix, payload)
    except Exception:
        log.exception("listener for %s failed", suffix)

