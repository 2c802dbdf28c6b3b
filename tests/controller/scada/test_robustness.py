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

from controller.scada.server import broken_mbap

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

    def close(self) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(10)
        for c in self.clients:
            c.close()


def test_garbage_on_one_connection_leaves_the_others_their_rate(serve):
    """Clean and garbage windows alternate many times (the sender is stopped and continued), so the
    machine's other load falls on both alike; the figure is a ratio of rates."""
    srv = serve()
    sender = subprocess.Popen([sys.executable, "-c", GARBAGE, str(srv.port), "1"], stdout=subprocess.PIPE, text=True)
    readers = Readers(srv.port)
    clean, dirty = [0, 0.0], [0, 0.0]
    try:
        assert sender.stdout.readline().strip() == "sending"
        for _ in range(16):
            sender.send_signal(signal.SIGSTOP)
            for total, (n, t) in ((clean, readers.window(0.12)),):
                total[0] += n
                total[1] += t
            sender.send_signal(signal.SIGCONT)
            for total, (n, t) in ((dirty, readers.window(0.12)),):
                total[0] += n
                total[1] += t
        assert sender.poll() is None and not readers.errors, readers.errors
    finally:
        sender.kill()
        sender.wait()
        readers.close()
    ratio = (dirty[0] / dirty[1]) / (clean[0] / clean[1])
    print(f"reads/s with a garbage connection / clean: {ratio:.2f} "
          f"({dirty[0] / dirty[1]:.0f} vs {clean[0] / clean[1]:.0f})")
    assert ratio >= 0.8, f"garbage cost the other connections {100 * (1 - ratio):.0f} % of their reads"
    assert srv.scada.server.broken > 0                 # it was garbage, and it was dropped
