"""hil_tests.ports: the loopback ports handed to servers the tests start lie below the kernel's
ephemeral range (so no outgoing connection can be given one before the server binds it), are free
when handed out, never handed out twice by one process, and the xdist workers draw from disjoint
slices."""
from __future__ import annotations

import socket

from hil_tests import ports


def test_ports_are_free_distinct_and_below_the_ephemeral_range():
    got = [ports.free_port() for _ in range(200)]
    assert len(set(got)) == len(got)
    assert all(ports.LOWEST <= p < max(ports.LOWEST + 1000, ports.ephemeral_start()) for p in got)
    for p in got[:20]:
        with socket.socket() as s:
            s.bind(("127.0.0.1", p))          # nobody holds it


def test_a_port_held_by_someone_is_not_handed_out(monkeypatch):
    taken, free = ports.free_port(), ports.free_port()
    held = socket.socket()
    held.bind(("127.0.0.1", taken))
    held.listen()
    try:
        monkeypatch.setattr(ports, "worker_slice", lambda low, high: [taken, free])
        monkeypatch.setattr(ports, "_given", set())
        assert ports.free_port() == free
    finally:
        held.close()


def test_xdist_workers_draw_from_disjoint_slices(monkeypatch):
    slices = []
    for k in range(3):
        monkeypatch.setenv("PYTEST_XDIST_WORKER", f"gw{k}")
        monkeypatch.setenv("PYTEST_XDIST_WORKER_COUNT", "3")
        slices.append(set(ports.worker_slice(20000, 32768)))
    assert all(len(s) > 4000 for s in slices)
    assert not (slices[0] & slices[1]) and not (slices[1] & slices[2]) and not (slices[0] & slices[2])
    monkeypatch.delenv("PYTEST_XDIST_WORKER")
    monkeypatch.delenv("PYTEST_XDIST_WORKER_COUNT")
    assert ports.worker_slice(20000, 32768) == range(20000, 32768)


def test_the_ephemeral_start_is_read_from_the_kernel_or_defaults(tmp_path):
    f = tmp_path / "range"
    f.write_text("40000\t60999\n")
    assert ports.ephemeral_start(str(f)) == 40000
    assert ports.ephemeral_start(str(tmp_path / "missing")) == 32768
