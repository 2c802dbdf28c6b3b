"""Free loopback TCP ports for the servers a test or a bench starts in other processes.

A port found by binding port 0 and closing the socket comes from the kernel's ephemeral range
(32768-60999 here), the range it also gives every outgoing connection: between the test closing it
and the controller binding it, any client connecting anywhere on the machine may be handed it
(seen in CI, 2026-12-03: the Zenoh listener of tests/controller/test_shutdown.py failed with
"Address already in use"). Below that range a port is only taken by someone binding it on
purpose, so ports come from there: each pytest-xdist worker from its own slice, each checked free
by binding it, none handed out twice by one process.
"""
from __future__ import annotations

import os
import random
import socket

LOWEST = 20000
_given: set[int] = set()
_pick = random.Random()             # seeded from the OS: two processes do not walk in step


def ephemeral_start(path: str = "/proc/sys/net/ipv4/ip_local_port_range") -> int:
    """The first port the kernel hands to outgoing connections (32768 where it does not say)."""
    try:
        with open(path) as fh:
            return int(fh.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def worker_slice(low: int, high: int) -> range:
    """This pytest-xdist worker's share of [low, high) (all of it outside xdist)."""
    name = os.environ.get("PYTEST_XDIST_WORKER", "")
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
    k = int(name[2:]) if name.startswith("gw") and name[2:].isdigit() else 0
    if count <= 1 or k >= count:
        return range(low, high)
    span = (high - low) // count
    return range(low + k * span, low + (k + 1) * span)


def free_port() -> int:
    """A loopback TCP port nobody holds now, below the ephemeral range, not handed out before here."""
    ports = worker_slice(LOWEST, max(LOWEST + 1000, min(ephemeral_start(), 32768)))
    for _ in range(500):
        port = _pick.choice(ports)
        if port in _given:
            continue
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        _given.add(port)
        return port
    raise RuntimeError(f"no free loopback port in {ports.start}-{ports.stop - 1}")
