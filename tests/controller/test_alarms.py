"""controller.alarms against a real SQLite ledger: an alarm is a condition (source, kind), not a text."""
from __future__ import annotations

import sqlite3

import pytest

from controller.alarms import TEXT_MAX, Alarms
from controller.store import MIGRATIONS, Store
from devices.clock import ManualClock

T0 = 1_780_000_000.0


class Published(list):
    def __call__(self, suffix, payload, reliable=False):
        self.append((suffix, payload, reliable))


@pytest.fixture
def ledger(tmp_path):
    return tmp_path / "ledger.db"


def make(ledger, clock=None):
    store, published = Store(ledger), Published()
    return Alarms(store, published, clock or ManualClock(T0)), store, published


def test_retried_alarm_with_varying_text_is_one_row_and_one_publish(ledger):
    alarms, store, published = make(ledger)
    news = []
    for i in range(100):
        alarms.clock.advance(0.5)
        news.append(alarms.raise_("device/rail", f"no status frame for {0.5 + i * 0.01:.2f} s",
                                  kind="unreachable"))
    assert news == [True] + [False] * 99
    assert len(store.alarms()) == 1 and len(published) == 1
    suffix, payload, reliable = published[0]
    assert suffix == "alarm/device/rail" and reliable
    first = alarms.clock.iso(T0 + 0.5)
    assert payload == {"t": first, "severity": "warning", "text": "no status frame for 0.50 s", "active": True,
                       "kind": "unreachable", "count": 1, "first_t": first, "last_t": first, "acked": False,
                       "acked_by": None, "acked_t": None}
    [shown] = alarms.listing()
    assert shown["text"] == "no status frame for 1.49 s" and shown["repeats"] == 99   # status: the latest
    assert (shown["count"], shown["first_t"], shown["last_t"]) == (100, first, alarms.clock.iso(T0 + 50))
    assert alarms.clear("device/rail", "connected") is True
    assert alarms.clear("device/rail", "connected") is False
    assert [(r["active"], r["text"]) for r in store.alarms()] == [(1, "no status frame for 0.50 s"),
                                                                 (0, "connected")]
    assert len(published) == 2 and published[1][1]["active"] is False and published[1][1]["count"] == 100
    [shown] = alarms.listing()          # cleared, unacknowledged: shown until someone acknowledges it
    assert shown["active"] is False and shown["acked"] is False and shown["text"] == "connected"
    assert [a.key for a in alarms.ack("ana")] == [("device/rail", "unreachable")]
    assert alarms.listing() == []


def test_severity_change_is_news_and_kinds_are_separate_conditions(ledger):
    alarms, store, published = make(ledger)
    assert alarms.raise_("sensor/T1-a", "stuck at 9 /s", kind="stuck")
    assert not alarms.raise_("sensor/T1-a", "stuck at 10 /s", kind="stuck")
    assert alarms.raise_("sensor/T1-a", "stuck at 10 /s", "critical", kind="stuck")
    assert alarms.raise_("sensor/T1-a", "silent", kind="dead")
    assert len(store.alarms()) == 3 and len(published) == 3
    assert "sensor/T1-a" in alarms.active and ("sensor/T1-a", "dead") in alarms.active
    assert alarms.active["sensor/T1-a"].kind == "stuck"           # the most severe of the source
    assert [a["kind"] for a in alarms.listing()] == ["stuck", "dead"]
    assert alarms.clear("sensor/T1-a", "recovered", kind="dead")
    assert ("sensor/T1-a", "dead") not in alarms.active and "sensor/T1-a" in alarms.active
    assert alarms.clear("sensor/T1-a", "recovered")                # every kind of the source
    assert "sensor/T1-a" not in alarms.active and len(store.alarms()) == 5


def test_cleared_then_raised_again_is_news(ledger):
    alarms, store, published = make(ledger)
    for _ in range(3):
        assert alarms.raise_("feeder", "fault: rail: timeout", kind="fault")
        assert alarms.clear("feeder", "back in service")
    assert len(store.alarms()) == 6 and len(published) == 6


def test_standing_alarms_reload_after_a_restart(ledger):
    alarms, store, _ = make(ledger)
    alarms.raise_("estop", "emergency stop: operator ana", "critical", kind="latched")
    alarms.raise_("device/rail", "cannot open: no adapter", kind="unreachable")
    alarms.raise_("sensor/T2-b", "stuck", kind="stuck")
    alarms.clear("sensor/T2-b", "recovered")
    store.close()
    again, store, published = make(ledger)
    assert set(again.active) == {("estop", "latched"), ("device/rail", "unreachable")}
    assert again.active["estop"].severity == "critical" and "estop" in again.active
    assert not again.raise_("device/rail", "cannot open: still no adapter", kind="unreachable")
    assert published == [] and len(store.alarms()) == 4
    assert again.clear("estop", "e-stop released") and "estop" not in again.active


def test_texts_are_escaped_and_bounded(ledger):
    alarms, store, published = make(ledger)
    alarms.raise_("estop", "emergency stop: operator x: " + "line\n2024 FORGED\x1b[2J" * 100_000, "critical")
    [row] = store.alarms()
    assert len(row["text"]) == TEXT_MAX and "\n" not in row["text"] and "\x1b" not in row["text"]
    assert published[0][1]["text"] == row["text"]
    alarms.raise_("estop", "y" * 10_000_000, "critical")   # a refresh is bounded as well
    assert len(alarms.listing()[0]["text"]) == TEXT_MAX
    assert alarms.raise_("feeder", "x", "fatal")          # never an exception on a safety path
    assert alarms.active["feeder"].severity == "critical"


def test_a_version_1_ledger_keeps_its_standing_alarms(ledger):
    db = sqlite3.connect(ledger)
    db.executescript(MIGRATIONS[0] + "; PRAGMA user_version = 1;")
    db.execute("INSERT INTO alarm (source, t, severity, text, active) VALUES ('estop', 1, 'critical', 'stop', 1)")
    db.execute("INSERT INTO alarm (source, t, severity, text, active) VALUES ('feeder', 2, 'warning', 'x', 1)")
    db.execute("INSERT INTO alarm (source, t, severity, text, active) VALUES ('feeder', 3, 'warning', 'ok', 0)")
    db.commit()
    db.close()
    alarms, store, _ = make(ledger)
    assert store.schema_version == len(MIGRATIONS)
    assert list(alarms.active) == [("estop", "general")]
    assert alarms.clear("estop", "released") and store.active_alarms() == []


def test_over_zenoh_a_hundred_retries_are_one_message(ledger):
    """The same through a real Bus to a subscriber on another session: the raise and the clear
    arrive (reliable, in order), the 99 refreshes in between do not."""
    import asyncio
    import queue
    import socket
    import threading
    import time

    from controller.bus import Bus
    from controller.config import BusConfig

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    server = Bus(BusConfig(mode="peer", listen=[endpoint]), "demo", loop=loop)
    client = Bus.client(endpoint, timeout_s=10, loop=loop)
    got, probed = queue.Queue(), threading.Event()

    async def listener(suffix, payload):
        if payload.get("probe"):
            probed.set()
        else:
            got.put((suffix, payload))
    try:
        client.subscribe("alarm/**", listener)
        deadline = time.monotonic() + 10
        while not probed.is_set():          # a route carries data a moment after it matches
            assert time.monotonic() < deadline, "no route to the subscriber"
            server.publish("alarm/device/rail", {"probe": True}, reliable=True)
            probed.wait(0.01)
        store = Store(ledger)
        alarms = Alarms(store, server.publish, ManualClock(T0))
        for i in range(100):
            alarms.raise_("device/rail", f"no status frame for {0.5 + i / 100:.2f} s", kind="unreachable")
        alarms.clear("device/rail", "connected")
        messages = []
        while not messages or messages[-1][1]["active"]:
            messages.append(got.get(timeout=10))
        assert [(s, p["active"], p["text"]) for s, p in messages] == [
            ("alarm/device/rail", True, "no status frame for 0.50 s"), ("alarm/device/rail", False, "connected")]
        assert len(store.alarms()) == 2
    finally:
        client.close()
        server.close()
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
        loop.close()
