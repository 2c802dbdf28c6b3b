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
    import threading
    import time

    from controller.bus import Bus
    from controller.config import BusConfig
    from hil_tests.ports import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
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


# ---------------------------------------------------------------- the alarm model (issue 8 part 5)

def test_count_first_and_last_seen_across_repeats_clears_and_raises(ledger):
    alarms, store, published = make(ledger)
    for i in range(5):
        alarms.clock.advance(1.0)
        alarms.raise_("device/rail", f"timeout {i}", kind="unreachable")
    alarms.clock.advance(1.0)
    alarms.clear("device/rail", "back")
    alarms.clock.advance(1.0)
    assert alarms.raise_("device/rail", "timeout again", kind="unreachable")     # news again
    a = alarms.known["device/rail", "unreachable"]
    assert (a.count, a.first_t, a.last_t, a.t, a.active) == (6, T0 + 1, T0 + 7, T0 + 7, True)
    assert len(store.alarms()) == 3 and len(published) == 3                      # raise, clear, raise
    assert published[1][1]["count"] == 5 and published[2][1]["count"] == 6


def test_acknowledged_but_active_stays_active_and_a_new_raise_needs_a_new_ack(ledger):
    alarms, store, published = make(ledger)
    alarms.raise_("feeder", "fault: rail", kind="fault")
    alarms.clock.advance(2.0)
    [acked] = alarms.ack("ana", "feeder")
    assert acked.acked_by == "ana" and acked.acked_t == T0 + 2 and ("feeder", "fault") in alarms.active
    assert published[-1][1] | {} == published[-1][1] and published[-1][1]["acked"] is True
    assert published[-1][1]["acked_by"] == "ana" and published[-1][1]["active"] is True
    [shown] = alarms.listing()
    assert shown["active"] and shown["acked"] and shown["acked_by"] == "ana"
    assert alarms.ack("bob", "feeder") == []                         # acknowledged once
    assert not alarms.raise_("feeder", "fault: rail again", kind="fault")      # a repeat: still acked
    assert alarms.known["feeder", "fault"].acked
    assert alarms.raise_("feeder", "fault: rail", "critical", kind="fault")    # worse: ack again
    assert not alarms.known["feeder", "fault"].acked
    alarms.ack("ana", "feeder", "fault")
    alarms.clear("feeder", "back in service")
    assert alarms.listing() == []                  # cleared and acknowledged: nothing to show
    alarms.raise_("feeder", "fault: rail", kind="fault")                       # raised again
    [shown] = alarms.listing()
    assert shown["acked"] is False and shown["acked_by"] is None and shown["count"] == 4
    with pytest.raises(LookupError):
        alarms.ack("ana", "nobody")
    with pytest.raises(LookupError):
        alarms.ack("ana", "feeder", "nokind")


def test_the_model_survives_a_restart(ledger):
    alarms, store, _ = make(ledger)
    for _ in range(3):
        alarms.raise_("sensor/T1-a", "stuck", kind="stuck")
    alarms.raise_("estop", "operator", "critical", kind="latched")
    alarms.ack("ana", "estop")
    alarms.raise_("feeder", "fault", kind="fault")
    alarms.clear("feeder")
    counts = {r["source"]: r["count"] for r in store.alarm_states()}
    assert counts["sensor/T1-a"] == 1                      # the repeats are held back...
    alarms.flush()                                         # ...until a clean stop writes them
    store.close()
    again, store, _ = make(ledger)
    assert set(again.active) == {("sensor/T1-a", "stuck"), ("estop", "latched")}
    assert again.known["sensor/T1-a", "stuck"].count == 3
    assert again.known["estop", "latched"].acked_by == "ana"
    assert [(a["source"], a["active"], a["acked"]) for a in again.listing()] == [
        ("estop", True, True), ("sensor/T1-a", True, False), ("feeder", False, False)]


def test_repeats_are_written_at_most_once_a_minute_not_once_each(ledger, monkeypatch):
    alarms, store, _ = make(ledger)
    writes = []
    save = store.save_alarm_state
    monkeypatch.setattr(store, "save_alarm_state", lambda **f: (writes.append(f["count"]), save(**f)))
    for _ in range(240):                      # two minutes of a retry every half second
        alarms.clock.advance(0.5)
        alarms.raise_("device/rail", "no status frame", kind="unreachable")
    assert writes[0] == 1 and 2 <= len(writes) <= 4
    assert store.alarm_states()[0]["count"] >= 240 - 2 * 60     # a crash loses under a minute's count
    alarms.clear("device/rail")
    assert store.alarm_states()[0]["count"] == 240              # the clear writes it exactly


def test_a_version_3_ledger_keeps_its_alarms_meaningful(ledger):
    db = sqlite3.connect(ledger)
    db.executescript(";".join(MIGRATIONS[:3]) + "; PRAGMA user_version = 3;")
    rows = [("estop", "latched", 1, "critical", "stop", 1), ("feeder", "fault", 2, "warning", "x", 1),
            ("feeder", "fault", 3, "warning", "ok", 0), ("feeder", "fault", 4, "warning", "y", 1),
            ("feeder", "fault", 5, "critical", "y", 1), ("sim", "exited", 6, "critical", "code 1", 1),
            ("sim", "exited", 7, "critical", "back", 0)]
    db.executemany("INSERT INTO alarm (source, kind, t, severity, text, active) VALUES (?, ?, ?, ?, ?, ?)", rows)
    db.commit()
    db.close()
    alarms, store, _ = make(ledger)
    assert set(alarms.active) == {("estop", "latched"), ("feeder", "fault")}
    f = alarms.known["feeder", "fault"]
    assert (f.count, f.first_t, f.last_t, f.severity, f.acked) == (3, 2, 5, "critical", False)
    s = alarms.known["sim", "exited"]
    assert not s.active and s.acked                # cleared before anyone could acknowledge: not shown
    assert [a["source"] for a in alarms.listing()] == ["estop", "feeder"]
    assert len(store.alarms()) == len(rows)        # the history is kept as it was
