"""Bad clients: garbage bytes, broken MBAP headers, truncated frames and half-open connections on
one connection never stall the others; idle connections are dropped; connections are capped."""
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import pytest

from controller.scada.framing import broken_mbap

from .mbap import Mbap

GARBAGE = r"""
import os, random, socket, sys, time
port, seed = int(sys.argv[1]), int(sys.argv[2])
rng = random.Random(seed)
sent = 0
print("sending", flush=True)
while True:
    try:
        s = socket.create_connection(("127.0.0.1", port), timeout=1)
        s.setblocking(False)
        for _ in range(rng.randint(1, 50)):
            kind = rng.random()
            if kind < 0.5:                       # random bytes
                chunk = os.urandom(rng.randint(1, 300))
            elif kind < 0.8:                     # a good header, a garbage PDU
                body = os.urandom(rng.randint(1, 20))
                chunk = rng.randbytes(2) + b"\x00\x00" + (len(body) + 1).to_bytes(2, "big") + b"\x01" + body
            else:                                # a header promising more than comes
                chunk = rng.randbytes(2) + b"\x00\x00\x00\x40\x01\x03\x00"
            s.send(chunk)
            sent += len(chunk)
            try:
                while s.recv(65536):
                    pass
            except (BlockingIOError, OSError):
                pass
            time.sleep(0.01)        # a steady trickle: the sender's own CPU is not what is measured
        s.close()
    except OSError:
        time.sleep(0.002)
"""


def closed_by_server(sock: socket.socket, within_s: float = 10.0) -> bool:
    """True when the server closes the connection (EOF or reset) before within_s."""
    sock.settimeout(within_s)
    try:
        while True:
            data = sock.recv(4096)
            if not data:
                return True
    except (ConnectionResetError, BrokenPipeError):
        return True
    except TimeoutError:
        return False


@pytest.mark.parametrize("header,broken", [(b"\x00\x01\x00\x00\x00\x06\x01", False),
                                           (b"\x00\x01\x12\x34\x00\x06\x01", True),     # protocol id
                                           (b"\x00\x01\x00\x00\x00\x00\x01", True),     # length 0
                                           (b"\x00\x01\x00\x00\x01\x00\x01", True),     # length 256
                                           (b"\x00\x01\x00\x00\x00\xfe\x01", False)])   # length 254: legal
def test_broken_headers(header, broken):
    assert broken_mbap(header) is broken


def test_a_broken_header_drops_that_connection_only(serve):
    srv = serve()
    good = Mbap(srv.port)
    try:
        for header in (b"\x00\x01\x12\x34\x00\x06\x01\x04\x00\x00\x00\x01", b"\x00\x01\x00\x00\xff\xff\x01\x04"):
            bad = socket.create_connection(("127.0.0.1", srv.port))
            bad.sendall(header)
            assert closed_by_server(bad)
            bad.close()
            assert isinstance(good.read("input register", 0, 10), list)
        # a well-framed PDU the server cannot decode gets an exception reply, the connection lives
        got, data = good.call(0x63, b"\x01\x02")
        assert (got, data[0]) == (0xE3, 1)                   # illegal function, under its own code
        assert isinstance(good.read("input register", 0, 10), list)
    finally:
        good.close()


@pytest.mark.parametrize("fc, body", [(4, struct.pack(">HH", 0, 0)), (4, struct.pack(">HH", 0, 126)),
                                      (3, struct.pack(">HH", 0, 0)), (1, struct.pack(">HH", 0, 2001)),
                                      (2, struct.pack(">HH", 0, 0)), (15, struct.pack(">HHB", 0, 0, 0)),
                                      (16, struct.pack(">HHB", 100, 0, 0)), (16, struct.pack(">HHBH", 100, 2, 4, 20))])
def test_a_request_with_a_quantity_its_function_does_not_allow_is_refused_with_03_under_its_code(serve, fc, body):
    """Modbus 1.1b3, 6.x: a quantity out of the function's range is exception 03 of that function
    (pymodbus answered a bare 0x80 01, which no client can match to its request)."""
    srv = serve()
    c = Mbap(srv.port)
    try:
        got, data = c.call(fc, body)
        assert (got, data[0]) == (fc | 0x80, 3)
        assert c.call(fc, body, unit=7)[0] == fc | 0x80           # another unit: still its own code
        assert isinstance(c.read("input register", 0, 10), list)
    finally:
        c.close()


@pytest.mark.parametrize("fc, body", [
    (5, struct.pack(">HH", 0, 0xFF00) + b"\x00"),              # an e-stop with a byte beyond it
    (5, struct.pack(">HH", 0, 0xFF00) + b"\xff\x00\x00\x00"),
    (6, struct.pack(">HH", 100, 20) + b"\x00"), (6, struct.pack(">H", 100) + b"\x00"),
    (4, struct.pack(">HH", 0, 4) + b"\x01\x02"), (3, struct.pack(">HHB", 0, 1, 0)), (1, struct.pack(">HHH", 0, 1, 0)),
    (16, struct.pack(">HHBH", 100, 1, 2, 20) + b"\x00\x00"), (15, struct.pack(">HHBB", 0, 1, 1, 1) + b"\x01"),
    (23, struct.pack(">HHHHBH", 0, 1, 100, 1, 2, 20) + b"\x00")])
def test_a_request_longer_or_shorter_than_its_fields_say_is_refused_with_03_and_not_acted_on(serve, fc, body):
    """The MBAP length counts bytes the request's own fields do not (a client's framing bug):
    pymodbus decoded the fields it wanted and acted, an e-stop among them."""
    from .conftest import StandIn
    stand_in = StandIn()
    srv = serve(stand_in)
    c = Mbap(srv.port)
    try:
        got, data = c.call(fc, body)
        assert (got, data[0]) == (fc | 0x80, 3)
        srv.call(lambda: None)
        assert stand_in.trips == [] and stand_in.calls == []
        assert isinstance(c.read("input register", 0, 10), list)        # the connection lives
    finally:
        c.close()


def test_idle_and_half_open_connections_are_dropped(serve):
    srv = serve(idle_timeout_s=0.3)
    silent = socket.create_connection(("127.0.0.1", srv.port))
    truncated = socket.create_connection(("127.0.0.1", srv.port))
    truncated.sendall(b"\x00\x01\x00\x00\x00\x06\x01\x04\x00")       # half a read request, then nothing
    busy = Mbap(srv.port)
    try:
        began = time.monotonic()
        while time.monotonic() - began < 1.0:        # three idle timeouts of steady polling: kept
            assert isinstance(busy.read("input register", 0, 4), list)
        assert closed_by_server(silent) and closed_by_server(truncated)
        assert srv.scada.server.idled >= 2
    finally:
        for s in (silent, truncated):
            s.close()
        busy.close()


def test_connections_are_capped(serve):
    srv = serve(max_connections=2)
    first, second = Mbap(srv.port), Mbap(srv.port)
    try:
        assert isinstance(first.read("input register", 0), list) and isinstance(second.read("input register", 0), list)
        third = socket.create_connection(("127.0.0.1", srv.port))
        assert closed_by_server(third)
        third.close()
        first.close()
        deadline = time.monotonic() + 10
        while True:                                   # the slot frees once the server sees the close
            try:
                again = Mbap(srv.port)
                assert isinstance(again.read("input register", 0), list)
                again.close()
                break
            except (ConnectionError, OSError):
                assert time.monotonic() < deadline, "a freed slot was never given again"
        assert isinstance(second.read("input register", 0), list)
    finally:
        second.close()


def test_at_the_cap_a_silent_connection_makes_room_and_an_e_stop_gets_through(serve):
    """A crashed HMI's half-open sockets (connected, never a byte more) held every slot: an e-stop
    from another client was refused for idle_timeout_s, and on again. The one silent longest (at
    least evict_after_s) now makes room; connections in use are never closed for a newcomer."""
    srv = serve(max_connections=2, idle_timeout_s=600.0)
    server = srv.scada.server
    silent = []
    busy = None
    try:
        for _ in range(2):      # one at a time: the server takes new connections in no set order
            silent.append(socket.create_connection(("127.0.0.1", srv.port)))
            while len(server.active_connections) < len(silent):
                time.sleep(0.001)
        deadline = time.monotonic() + server.evict_after_s
        while time.monotonic() < deadline - server.evict_after_s / 2:   # not silent long enough: refused
            third = socket.create_connection(("127.0.0.1", srv.port))
            assert closed_by_server(third)
            third.close()
        while True:        # a slot frees for the newcomer once one is silent for evict_after_s
            try:
                busy = Mbap(srv.port)
                assert busy.write("coil", 0, [1]) is None               # the e-stop coil
                break
            except (ConnectionError, OSError):
                assert time.monotonic() < deadline + 10, "no silent connection made room"
        assert srv.controller.trips and server.evicted >= 1 and server.idled == 0
        assert sum(closed_by_server(s, 5.0) for s in silent) >= 1
        # the newcomer is in use: a fourth connection does not close it
        fourth = socket.create_connection(("127.0.0.1", srv.port))
        assert busy.read("input register", 0) is not None and isinstance(busy.read("input register", 0), list)
        fourth.close()
    finally:
        for s in silent:
            s.close()
        if busy is not None:
            busy.close()


class Readers:
    """Four SCADA connections polling a tank block as fast as the server answers, counting."""

    def __init__(self, port: int, n: int = 4):
        self.clients = [Mbap(port) for _ in range(n)]
        self.counts = [0] * n
        self.errors: list = []
        self.stop = threading.Event()
        self.threads = [threading.Thread(target=self._poll, args=(i,)) for i in range(n)]
        for t in self.threads:
            t.start()

    def _poll(self, i: int) -> None:
        try:
            while not self.stop.is_set():
                assert len(self.clients[i].read("input register", 100, 20)) == 20
                self.counts[i] += 1
        except Exception as exc:          # noqa: BLE001 - reported by the test
            self.errors.append(exc)

    def window(self, seconds: float) -> tuple[int, float]:
        """Reads done over a window of about ``seconds``, and its exact length."""
        n0, t0 = sum(self.counts), time.perf_counter()
        time.sleep(seconds)
        return sum(self.counts) - n0, time.perf_counter() - t0

    def alternate(self, sender: subprocess.Popen, windows: int, window_s: float = 0.12):
        """``windows`` pairs of windows, the sender stopped in the first and continued in the second
        (the machine's other load falls on both alike): (clean reads/s, garbage reads/s, each
        poller's reads in the garbage windows)."""
        clean, dirty, answered = [0, 0.0], [0, 0.0], [0] * len(self.counts)
        for _ in range(windows):
            sender.send_signal(signal.SIGSTOP)
            n, t = self.window(window_s)
            clean[0], clean[1] = clean[0] + n, clean[1] + t
            sender.send_signal(signal.SIGCONT)
            before = list(self.counts)
            n, t = self.window(window_s)
            dirty[0], dirty[1] = dirty[0] + n, dirty[1] + t
            answered = [a + now - then for a, now, then in zip(answered, self.counts, before, strict=True)]
        return clean[0] / clean[1], dirty[0] / dirty[1], answered

    def close(self) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(10)
        for c in self.clients:
            c.close()


def test_garbage_on_one_connection_leaves_the_others_served(serve):
    """Clean and garbage windows alternate (the sender is stopped and continued). Every poller is
    answered while garbage flows, and their rate stays of the clean one's order (a server that
    waits on a frame that never completes falls to nothing). The ratio itself is load-dependent
    (0.86-0.95 on a machine to itself, 0.79 once on a CI runner shared by three workers), so its
    figure is bench/'s: ``bench/bench_scada_garbage.py``."""
    srv = serve()
    sender = subprocess.Popen([sys.executable, "-c", GARBAGE, str(srv.port), "1"], stdout=subprocess.PIPE, text=True)
    readers = Readers(srv.port)
    try:
        assert sender.stdout.readline().strip() == "sending"
        clean, dirty, answered = readers.alternate(sender, 16)
        assert sender.poll() is None and not readers.errors, readers.errors
    finally:
        sender.kill()
        sender.wait()
        readers.close()
    ratio = dirty / clean
    print(f"reads/s with a garbage connection / clean: {ratio:.2f} ({dirty:.0f} vs {clean:.0f})")
    assert 0 not in answered, f"a poller had no answer while garbage flowed: {answered}"
    assert ratio >= 0.5, f"garbage cost the other connections {100 * (1 - ratio):.0f} % of their reads"
    assert srv.scada.server.broken > 0                 # it was garbage, and it was dropped


def _frame(tid: int, fc: int, body: bytes, unit: int = 1) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(body) + 2, unit) + bytes([fc]) + body


def _reply(sock: socket.socket) -> tuple[int, int, bytes]:
    """(transaction id, function code, data) of the next reply."""
    head = b""
    while len(head) < 7:
        chunk = sock.recv(7 - len(head))
        assert chunk, "closed by the server"
        head += chunk
    tid, _, length, _ = struct.unpack(">HHHB", head)
    body = b""
    while len(body) < length - 1:
        chunk = sock.recv(length - 1 - len(body))
        assert chunk, "closed by the server"
        body += chunk
    return tid, body[0], body[1:]


def test_pipelined_requests_are_each_answered_in_order_an_estop_among_them_acting(serve):
    """Modbus TCP lets a client send its next request before the last reply: pymodbus took the first
    frame of a read and dropped the rest as it replied, an e-stop write among them included."""
    from .conftest import StandIn
    stand_in = StandIn()
    srv = serve(stand_in)
    s = socket.create_connection(("127.0.0.1", srv.port), timeout=10)
    try:
        s.sendall(_frame(1, 4, struct.pack(">HH", 0, 4)) + _frame(2, 5, struct.pack(">HH", 0, 0xFF00))
                  + _frame(3, 1, struct.pack(">HH", 0, 1)))
        replies = [_reply(s) for _ in range(3)]
        assert [(tid, fc) for tid, fc, _ in replies] == [(1, 4), (2, 5), (3, 1)]
        assert replies[1][2] == struct.pack(">HH", 0, 0xFF00)          # the write echoed
        srv.call(lambda: None)
        assert stand_in.trips == ["modbus e-stop by scada"]              # on arrival, once
        assert [call[0] for call in stand_in.calls] == ["estop"]
        # more frames in one send than a connection queues: every one answered, in order
        many = [_frame(tid, 4, struct.pack(">HH", tid % 7, 1 + tid % 3)) for tid in range(10, 210)]
        s.sendall(b"".join(many))
        got = [_reply(s) for _ in many]
        assert [(tid, fc, len(data)) for tid, fc, data in got] == [(tid, 4, 1 + 2 * (1 + tid % 3))
                                                                   for tid in range(10, 210)]
    finally:
        s.close()


def test_a_request_cut_across_a_reply_is_still_whole(serve):
    """A frame whose first bytes came with the previous request is not lost when that one is answered
    (pymodbus emptied the receive buffer as it replied)."""
    srv = serve()
    s = socket.create_connection(("127.0.0.1", srv.port), timeout=10)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    try:
        second = _frame(8, 3, struct.pack(">HH", 100, 2))
        for cut in range(1, len(second)):
            s.sendall(_frame(7, 4, struct.pack(">HH", 0, 1)) + second[:cut])
            assert _reply(s)[:2] == (7, 4)
            s.sendall(second[cut:])
            assert _reply(s)[:2] == (8, 3), f"cut at byte {cut}"
    finally:
        s.close()


def test_a_frame_trickled_a_byte_at_a_time_is_dropped_after_the_idle_timeout(serve):
    """Bytes that never make a whole frame hold no slot for good: any byte used to count as heard."""
    srv = serve(idle_timeout_s=1.5)
    slow = socket.create_connection(("127.0.0.1", srv.port))
    try:
        slow.sendall(b"\x00\x01\x00\x00\x00\xfe\x01")       # a header promising 253 bytes of PDU
        slow.settimeout(0.25)
        began = time.monotonic()
        closed = False
        while not closed and time.monotonic() - began < 8:
            try:
                slow.send(b"\x03")                 # a byte every 0.25 s: never silent for 1.5 s
                closed = slow.recv(64) == b""
            except TimeoutError:
                pass
            except (ConnectionResetError, BrokenPipeError):
                closed = True
        assert closed, "a trickling frame kept its connection for 8 s"
        assert srv.scada.server.idled >= 1
    finally:
        slow.close()


def test_functions_the_map_does_not_serve_are_refused_with_01(serve):
    """pymodbus answers diagnostics, event counters and FIFO queues from its own counters or
    invented data (FC 24 read 0, 1, 2, 3); the map serves reads, writes and the identification."""
    srv = serve()
    c = Mbap(srv.port)
    try:
        for fc, body in ((7, b""), (8, b"\x00\x00\x12\x34"), (11, b""), (12, b""), (17, b""),
                         (22, struct.pack(">HHH", 100, 0xFFFF, 0)), (24, struct.pack(">H", 100)),
                         (20, b"\x07\x06\x00\x01\x00\x00\x00\x01"), (0x84, b"\x02")):
            got, data = c.call(fc, body)
            assert (got, data[0]) == (fc | 0x80, 1), fc
        got, data = c.call(43, b"\x0e\x01\x00")                       # the identification still answers
        assert got == 43 and b"fishfarm" in data
    finally:
        c.close()


def test_an_estop_behind_a_flood_of_pipelined_writes_trips_at_once_and_the_writes_are_all_answered(serve):
    """An e-stop sent after thousands of writes in one go sat in the kernel's buffer for minutes
    (reading paused until the writes were answered), and the connection, silent while it waited
    for its replies, was dropped as idle with the e-stop unread."""
    from .conftest import StandIn

    class Slow(StandIn):
        async def apply(self, command, payload, *, user=None, origin="zenoh"):
            if command == "ration":
                await asyncio.sleep(0.005)               # each write an override that takes a while
            return await super().apply(command, payload, user=user, origin=origin)

    import asyncio
    stand_in = Slow()
    srv = serve(stand_in, idle_timeout_s=0.5)
    s = socket.create_connection(("127.0.0.1", srv.port), timeout=30)
    try:
        writes = [_frame(tid, 16, struct.pack(">HHBHH", 101, 2, 4, 0x4120, 0)) for tid in range(1, 2001)]   # 10 g
        sent = time.monotonic()
        s.sendall(b"".join(writes) + _frame(2001, 5, struct.pack(">HH", 0, 0xFF00)))
        while not srv.call(lambda: list(stand_in.trips)):
            assert time.monotonic() - sent < 5.0, "the e-stop waited behind the writes"
            time.sleep(0.01)
        tripped_after = sum(call[0] == "ration" for call in srv.call(lambda: list(stand_in.calls)))
        replies = [_reply(s) for _ in range(2001)]         # over 10 s of writes: never dropped as idle
        assert [(tid, fc) for tid, fc, _ in replies] == [(tid, 16) for tid in range(1, 2001)] + [(2001, 5)]
        assert tripped_after < 2000                         # tripped while writes still waited
    finally:
        s.close()


@pytest.mark.parametrize("behind", ["flood", "broken header"])
def test_an_estop_tripped_on_a_connection_then_closed_is_still_recorded(serve, behind):
    """The e-stop frame trips the latches as it arrives; its request was then thrown away when the
    connection was closed (over 10,000 requests waiting, or a broken header behind it): the devices
    latched while status, coil 0 and the audit said nothing, and a reset was refused as needless."""
    from controller.scada.server import PIPELINE_MAX

    from .conftest import StandIn
    stand_in = StandIn()
    srv = serve(stand_in)
    s = socket.create_connection(("127.0.0.1", srv.port), timeout=30)
    try:
        estop = _frame(60000, 5, struct.pack(">HH", 0, 0xFF00))
        reads = [_frame(tid, 4, struct.pack(">HH", 0, 1)) for tid in range(PIPELINE_MAX + 400)]
        tail = b"".join(reads[100:]) if behind == "flood" else b"\x00\x01\x00\x09\x00\x06\x01\x04\x00\x00\x00\x01"
        s.sendall(b"".join(reads[:100]) + estop + tail)
        assert closed_by_server(s)
    finally:
        s.close()
    deadline = time.monotonic() + 10
    while not [c for c in srv.call(lambda: list(stand_in.calls)) if c[0] == "estop"]:
        assert time.monotonic() < deadline, "the e-stop tripped but never reached the controller"
        time.sleep(0.01)
    [(command, payload, _, origin)] = [c for c in srv.call(lambda: list(stand_in.calls)) if c[0] == "estop"]
    assert len(srv.call(lambda: list(stand_in.trips))) == 1 and origin.startswith("modbus 127.0.0.1:")
    assert "closed before the reply" in payload["reason"]


def test_a_write_under_way_when_its_client_goes_is_carried_out_whole(serve):
    """The client's going cancelled the write's wait, and with it the override half done on the
    controller's loop (a ration set, or not, by a closed socket's timing)."""
    import asyncio

    from .conftest import StandIn

    class Slow(StandIn):
        async def apply(self, command, payload, *, user=None, origin="zenoh"):
            reply = await super().apply(command, payload, user=user, origin=origin)
            await asyncio.sleep(0.3)                  # an override that takes a while (a ledger write)
            self.done.append(command)
            return reply

    stand_in = Slow()
    stand_in.done = []
    srv = serve(stand_in)
    s = socket.create_connection(("127.0.0.1", srv.port), timeout=30)
    s.sendall(_frame(1, 16, struct.pack(">HHBHH", 101, 2, 4, 0x4120, 0)))      # T1's ration: 10 g
    deadline = time.monotonic() + 10
    while not srv.call(lambda: list(stand_in.calls)):
        assert time.monotonic() < deadline
        time.sleep(0.005)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    s.close()                                         # reset, while the override is under way
    while not srv.call(lambda: list(stand_in.done)):
        assert time.monotonic() < deadline, "the write was dropped half done"
        time.sleep(0.01)
    assert stand_in.done == ["ration"]
