"""The Modbus TCP server for SCADA (pymodbus 3.16), inside the controller process.

Reads are answered from the coordinator's snapshot, never from a device. Writes are guarded by the
register map (controller/scada/guard.py) and each accepted one becomes an override through
``controller.overrides.apply`` — the e-stop coil trips the latches first, synchronously.

pymodbus's request PDUs talk to their datastore through two calls, ``async_getValues`` and
``async_setValues`` (pymodbus/pdu/*: ``datastore_update``), and turn an ``ExcCodes`` returned
into the exception response: ``ScadaStore`` is that datastore, built on the map rather than on
pymodbus's (deprecated) memory blocks; requests are decoded strictly (controller/scada/framing.py).
Each connection is a ``ServerRequestHandler`` subclass that drops a client whose MBAP header cannot
be a Modbus TCP frame (pymodbus would wait on it for good), notes when it last heard the client
(idle connections are dropped), and names the peer for the audit. Beyond ``max_connections`` a
new connection takes the place of the one silent longest (``evict_silent``), or is closed at once
when every one is in use.
"""
from __future__ import annotations

import asyncio
import collections
import contextlib
import contextvars
import logging
import time

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ModbusIOException, NoSuchIdException
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.device import ModbusDeviceIdentification
from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.transaction import TransactionManager

from controller.scada.framing import READ_KIND, WRITE_KIND, StrictDecoder, broken_mbap
from controller.scada.guard import Guard
from controller.scada.register_map import COIL, DI, HR, Layout

log = logging.getLogger("fishfarm.scada")

PEER: contextvars.ContextVar = contextvars.ContextVar("scada_peer", default=None)   # the _Connection
ECHO: contextvars.ContextVar[list | None] = contextvars.ContextVar("scada_echo", default=None)
# Requests one connection may have waiting. Its stream is always read (an e-stop frame behind a
# flood of writes must reach the latches as it arrives, not once the writes are answered: with
# reading paused, one sat in the kernel's buffer for minutes); a client further ahead than this is
# closed, its e-stops among what was read tripped first
PIPELINE_MAX = 10_000
EVICT_AFTER_S = 2.0           # wall: at the cap, a connection silent this long makes room for a new one
REFUSED_SAID_EVERY_S = 60.0   # wall: a refusal is logged at most this often (with the count)


class ScadaStore:
    """The datastore the request PDUs call."""

    def __init__(self, lay: Layout, cfg, coordinator, guard: Guard):
        self.lay, self.cfg, self.coordinator, self.guard = lay, cfg, coordinator, guard
        self.act_loop: asyncio.AbstractEventLoop | None = None   # the controller's (Scada.run sets it before
                                                                 # listening): writes act there

    def device_ids(self) -> list[int]:
        return [self.cfg.unit]

    def _unit(self, device_id: int) -> None:
        if device_id != self.cfg.unit:
            raise NoSuchIdException(f"unit {device_id}")    # pymodbus answers exception 0B

    def unreadable(self, request: ModbusPDU) -> ExcCodes | None:
        """A read/write request's (FC 23) read range, checked before its write acts: pymodbus writes
        first, so a read past the map answered 02 after feeding the tank — and a SCADA that gets an
        exception sends the write again. None for every other request, and for a range the map has."""
        count = getattr(request, "read_count", None) if request.function_code == 23 else None
        if count is None or not 1 <= count <= request.MAX_READ_COUNT:    # a count it cannot take: 03, as ever
            return None
        self._unit(request.dev_id)
        return None if request.read_address + count <= len(self.coordinator.image[HR]) else ExcCodes.ILLEGAL_ADDRESS

    async def async_getValues(self, device_id: int, func_code: int, address: int, count: int = 1):
        self._unit(device_id)
        if func_code in (5, 6):          # a single write's reply echoes what was written
            echo = ECHO.get()
            return echo if echo is not None else ExcCodes.ILLEGAL_FUNCTION
        kind = READ_KIND.get(func_code)
        if kind is None:
            return ExcCodes.ILLEGAL_FUNCTION
        image = self.coordinator.image[kind]
        if address < 0 or count < 1 or address + count > len(image):
            return ExcCodes.ILLEGAL_ADDRESS
        words = image[address:address + count]
        return [bool(w) for w in words] if kind in (COIL, DI) else words

    async def async_setValues(self, device_id: int, func_code: int, address: int, values):
        self._unit(device_id)
        kind = WRITE_KIND.get(func_code)
        if kind is None:
            return ExcCodes.ILLEGAL_FUNCTION
        values = list(values) if isinstance(values, (list, tuple)) else [values]
        if func_code in (5, 6):
            ECHO.set(values)
        conn = PEER.get()
        write = self.guard.write(kind, address, values, conn.peer if conn is not None else "?",
                                 tripped=conn is not None and conn.take_trip())
        # a write taken is carried out whole, though its client goes (the reply is then lost):
        # cancelling the wait cancelled the write half done on the controller's loop
        return await self._on_act_loop(write)

    async def refuse_unreadable(self, request: ModbusPDU, code: ExcCodes, peer: str) -> None:
        """Audit an FC 23 refused for its read range (its write was not acted on)."""
        refused = self.guard.refused_read(
            HR, request.write_address, list(request.write_registers), peer, code,
            f"read of {request.read_count} from {request.read_address}: past the map")
        await self._on_act_loop(refused)

    async def _on_act_loop(self, coro):
        """``coro`` run on the controller's loop, awaited here; carried out whole though the wait is
        cancelled (its connection gone)."""
        return await asyncio.shield(asyncio.wrap_future(asyncio.run_coroutine_threadsafe(coro, self.act_loop)))

    def estops_unanswered(self, count: int, peer: str) -> None:
        """E-stops tripped on arrival on a connection closed before they were answered."""
        for _ in range(count):
            asyncio.run_coroutine_threadsafe(self.guard.estop_unanswered(peer), self.act_loop)


class _Connection(ServerRequestHandler):
    """One client. Every complete frame a read brings is taken (a client may send its next request
    before the last one's reply: Modbus TCP allows it) and answered in order, one at a time, each
    with its own transaction id; pymodbus alone took the first and dropped the rest when it replied."""
    peer = "?"
    last_heard = 0.0
    frame_started: float | None = None       # when the frame now cut short began to arrive
    tripped = 0                              # e-stop frames tripped on arrival, not yet acted on
    answering: asyncio.Task | None = None
    waiting: collections.deque | tuple = ()     # each connection's own from callback_connected

    def take_trip(self) -> bool:
        """Whether this request's e-stop was tripped on arrival (then the guard does not again)."""
        if self.tripped:
            self.tripped -= 1
            return True
        return False

    def callback_connected(self) -> None:
        super().callback_connected()
        self.last_heard = time.monotonic()
        self.waiting: collections.deque = collections.deque()
        self.answering: asyncio.Task | None = None
        with contextlib.suppress(Exception):
            host, port = self.transport.get_extra_info("peername")[:2]
            self.peer = f"{host}:{port}"
        server = self.server
        if len(server.active_connections) > server.scada.max_connections and not server.evict_silent(self):
            server.refused += 1
            now = time.monotonic()
            if now - server.refused_said >= REFUSED_SAID_EVERY_S:     # a storm is one line a minute
                log.warning("scada: %d connections, none silent for %g s; refusing %s (%d refused so far)",
                            server.scada.max_connections, server.evict_after_s, self.peer, server.refused)
                server.refused_said = now
            self.close()

    def callback_disconnected(self, exc: Exception | None) -> None:
        super().callback_disconnected(exc)
        self._drop_waiting()

    def close(self, reconnect: bool = False) -> None:
        # (pymodbus calls no callback_disconnected for a close of our own)
        self._drop_waiting()
        super().close(reconnect)

    def _drop_waiting(self) -> None:
        """Requests a closed connection can no longer be answered are dropped (a write being carried
        out is finished: ScadaStore.async_setValues). But e-stop frames tripped on arrival whose
        requests are among them (closed with over PIPELINE_MAX waiting, a broken frame behind them,
        the client gone) latched the devices: the controller records them all the same, or status,
        coil 0 and reset would read no e-stop while the devices hold one."""
        if self.answering is not None:
            self.answering.cancel()
        if self.waiting:
            self.waiting.clear()
        unanswered, self.tripped = self.tripped, 0
        if unanswered:
            self.server.context.estops_unanswered(unanswered, self.peer)

    def datagram_received(self, data: bytes, addr: tuple | None) -> None:
        # pymodbus's own emptied the buffer whole once it held more than one frame's 260 bytes
        self.recv_buffer += data
        self.recv_buffer = self.recv_buffer[self.callback_data(self.recv_buffer, addr):]

    def callback_data(self, data: bytes, addr: tuple | None = None) -> int:
        """Takes the complete frames at the front of ``data`` (the connection's whole buffer);
        returns how many bytes they were. A client with more than PIPELINE_MAX requests waiting is
        closed."""
        now = self.last_heard = time.monotonic()
        used = 0
        while used + 6 <= len(data):           # frame by frame, each sliced alone (not the rest: quadratic)
            head = data[used:used + 6]
            if broken_mbap(head):
                self.server.broken += 1
                log.debug("scada: %s sent a broken MBAP header; dropped", self.peer)
                self.close()
                return len(data)
            end = used + 6 + int.from_bytes(head[4:6], "big")
            if end > len(data):
                break                          # not whole yet
            frame = data[used:end]
            if self.server.urgent is not None and self.server.estop_frame(frame):
                self.tripped += 1
                self.server.urgent()       # the latches now, before pymodbus parses the request
            if self._take(frame, addr) is None:
                return len(data)
            used = end
        if used:
            self.frame_started = None
        if used < len(data) and self.frame_started is None:
            self.frame_started = now      # a frame begun: it has idle_timeout_s to arrive whole
        if len(self.waiting) > PIPELINE_MAX:
            log.warning("scada: %s has over %d requests waiting; closed", self.peer, PIPELINE_MAX)
            self.server.broken += 1
            self.close()
            return len(data)
        if self.waiting and self.answering is None:
            self.answering = asyncio.ensure_future(self._answer_waiting())
        return used

    def _take(self, frame: bytes, addr) -> bool | None:
        """One whole frame, queued; None when the connection is closed."""
        try:
            TransactionManager.callback_data(self, frame, addr)
        except ModbusIOException as exc:         # as pymodbus answers it
            self.waiting.append((ExceptionResponse(exc.fcode or 0, ExcCodes.ILLEGAL_FUNCTION,
                                                   device_id=exc.dev_id, transaction=exc.transaction_id), addr))
            return True
        except Exception as exc:     # a frame pymodbus cannot take apart: this client only loses
            self.server.broken += 1
            log.debug("scada: %s: undecodable frame (%s); dropped", self.peer, exc)
            self.close()
            return None
        if self.last_pdu is not None:
            self.waiting.append((self.last_pdu, addr))
            self.last_pdu = None
        return True

    async def _answer_waiting(self) -> None:
        try:
            while self.waiting:
                request, addr = self.waiting.popleft()
                # a task of its own per request: the audit's peer and a write's echo are its alone
                await asyncio.ensure_future(self._answer(request, addr))
        finally:
            self.answering = None

    async def _answer(self, request: ModbusPDU, addr) -> None:
        if isinstance(request, ExceptionResponse):
            self.server_send(request, addr)
            return
        PEER.set(self)
        try:
            unread = self.server.context.unreadable(request)
            if unread is not None:          # FC 23 writes before it reads: both are checked first
                await self.server.context.refuse_unreadable(request, unread, self.peer)
                response = ExceptionResponse(request.function_code, unread)
            else:
                response = await request.datastore_update(self.server.context, request.dev_id)
        except NoSuchIdException:
            response = ExceptionResponse(request.function_code, ExcCodes.GATEWAY_NO_RESPONSE)
        except Exception:        # a bug: this request answers 04, the server goes on
            log.exception("scada: %s: request fc %d failed", self.peer, request.function_code)
            response = ExceptionResponse(request.function_code, ExcCodes.DEVICE_FAILURE)
        response.transaction_id, response.dev_id = request.transaction_id, request.dev_id
        self.server_send(response, addr)
        self.last_heard = time.monotonic()        # traffic either way: a client reading its replies is not idle

    def send(self, data: bytes, addr: tuple | None = None) -> None:
        # pymodbus empties the receive buffer as it replies: the next request's first bytes with it
        kept = self.recv_buffer
        super().send(data, addr)
        self.recv_buffer = kept


def _silent_since(conn, now: float) -> float:
    """Since when ``conn`` has been silent, or trickling one frame (a byte every few seconds held a
    slot for good); ``now`` while it has requests waiting for our replies."""
    if getattr(conn, "waiting", None):
        return now
    return min(getattr(conn, "last_heard", now), getattr(conn, "frame_started", None) or now)


class ScadaServer(ModbusTcpServer):
    def __init__(self, store: ScadaStore, scada_cfg, site: str):
        identity = ModbusDeviceIdentification(info_name={
            "VendorName": "fishfarm", "ProductCode": "fishfarm-controller",
            "ProductName": "fishfarm controller", "ModelName": f"site {site}",
            "MajorMinorRevision": "map 1"})
        # the placeholder device satisfies the constructor; every request goes to ``store``
        super().__init__(SimDevice(scada_cfg.unit, simdata=SimData(0, datatype=DataType.REGISTERS)),
                         address=(scada_cfg.listen, scada_cfg.port), identity=identity)
        self.context = store
        self.decoder = StrictDecoder()       # each connection's framer takes it when it opens
        self.scada = scada_cfg
        self.refused = self.broken = self.idled = self.evicted = 0
        self.refused_said = -REFUSED_SAID_EVERY_S
        self.urgent = None           # set by the service: trips the e-stop latches
        # the one frame acted on before parsing, as Zenoh's estop is: a complete FC 5 writing ON
        # to the e-stop coil, for this unit, with writes allowed — always a write the guard takes
        coil = next(e.address for e in store.lay.by_kind(COIL) if e.name == "estop")
        self._estop = None if scada_cfg.read_only else (
            b"\x00\x00\x00\x06" + bytes([scada_cfg.unit, 5]) + coil.to_bytes(2, "big") + b"\xff\x00")

    def estop_frame(self, data: bytes) -> bool:
        return self._estop is not None and len(data) == 12 and data[2:] == self._estop

    def callback_new_connection(self):
        conn = _Connection(self, self.trace_packet, self.trace_pdu, self.trace_connect)
        conn.last_heard = time.monotonic()     # just come, not silent: its callback_connected may come later
        return conn

    @property
    def port(self) -> int | None:
        sockets = getattr(self.transport, "sockets", None)
        return sockets[0].getsockname()[1] if sockets else None

    @property
    def evict_after_s(self) -> float:
        return min(EVICT_AFTER_S, self.scada.idle_timeout_s / 4)

    def evict_silent(self, newcomer) -> bool:
        """At the cap, make room for ``newcomer`` by closing the connection silent longest, if it has
        been silent ``evict_after_s`` (with no request waiting): eight half-open sockets of a crashed
        HMI refused every other client, e-stops among them, for ``idle_timeout_s`` and on again.
        A client polling does not go quiet that long; a client closed this way may reconnect."""
        now = time.monotonic()
        silent = [c for c in self.active_connections.values()
                  if c is not newcomer and now - _silent_since(c, now) >= self.evict_after_s]
        if not silent:
            return False
        oldest = min(silent, key=lambda c: _silent_since(c, now))
        log.info("scada: %d connections; closed %s, silent %.0f s, for %s", self.scada.max_connections,
                 getattr(oldest, "peer", "?"), now - _silent_since(oldest, now), newcomer.peer)
        oldest.close()
        self.evicted += 1
        return True

    def drop_idle(self, now: float | None = None) -> int:
        """Close the connections silent for ``idle_timeout_s``, or that long on one frame: a half-open or
        trickling one holds no slot for good."""
        now = time.monotonic() if now is None else now
        dropped = 0
        for conn in list(self.active_connections.values()):
            since = _silent_since(conn, now)
            if now - since > self.scada.idle_timeout_s:
                log.debug("scada: %s idle or mid-frame for %.0f s; dropped", getattr(conn, "peer", "?"), now - since)
                conn.close()
                dropped += 1
        self.idled += dropped
        return dropped

    async def watch_idle(self) -> None:
        while True:
            await asyncio.sleep(min(1.0, self.scada.idle_timeout_s / 4))
            self.drop_idle()


__all__ = ["ECHO", "PEER", "ScadaServer", "ScadaStore", "broken_mbap"]
