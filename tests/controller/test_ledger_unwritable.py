"""A ledger that cannot be written (a full disk, made here with SQLite's ``max_page_count`` on the
real file): the store says so once and raises ``LedgerUnwritable``; alarms still stand and are
published, and are written once it can be; today's ration still shows; an override is refused
naming the ledger and its audit row waits; the controller's ``ledger`` alarm comes and goes once;
and the feeding robot on its real drivers feeds nothing until the ledger takes its intent, then
serves the demand once (controller/ledger_writes.py)."""
from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import resource
import signal
import sqlite3
from types import SimpleNamespace

import pytest

from controller.alarms import Alarms
from controller.app import Controller
from controller.overrides import Overrides
from controller.store import LedgerUnwritable, Store
from devices.clock import ManualClock
from tests.controller.feeding.rig import rig
from tests.controller.override_rig import Farm


@contextlib.contextmanager
def disk_full(store: Store):
    """No file of this process may grow (RLIMIT_FSIZE; SIGXFSZ ignored, so a write fails with
    EFBIG as on a full disk): the ledger's write-ahead log, emptied first, can take no commit.
    Reads go on. Only ``free`` or the block's end lifts it."""
    store.db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    before = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    limits = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (1, limits[1]))
    try:
        yield lambda: resource.setrlimit(resource.RLIMIT_FSIZE, limits)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, limits)
        signal.signal(signal.SIGXFSZ, before)


def big_write(store: Store, n: int = 1) -> None:
    for _ in range(n):
        store.add_stock_event(t=1.0, tank="T1", kind="mortality", count=1, to_tank=None, who="x" * 900)


# SQLite's words, and why (the simulated full disk is this process's file-size limit)
CAUSE = "disk I/O error (the file-size limit of this process, ulimit -f: 1 bytes, reached)"


@pytest.fixture
def store(tmp_path):
    s = Store(tmp_path / "ledger.db")
    yield s
    s.close()


def test_a_full_ledger_is_said_once_each_way_and_its_cause_is_not_masked(store, caplog):
    caplog.set_level(logging.INFO, "fishfarm.store")
    with disk_full(store) as free:
        for write in (lambda: big_write(store),                      # one statement
                      lambda: store.add_audits([dict(t=1.0, user=None, operator="ana", command="x", payload=None,
                                                     origin="o", ok=True, result="ok", reply=None)] * 9)):
            with pytest.raises(LedgerUnwritable, match=re.escape(CAUSE)):
                write()
        assert store.unwritable == CAUSE and not store.db.in_transaction
        assert [r.levelname for r in caplog.records] == ["ERROR"]
        assert f"ledger: cannot write: {CAUSE}" in caplog.records[0].getMessage()
        free()
        big_write(store, 2)
    assert isinstance(LedgerUnwritable("x"), sqlite3.OperationalError)   # old handlers still catch it
    assert store.unwritable is None and len(store.stock_events()) == 2
    assert [r.levelname for r in caplog.records] == ["ERROR", "WARNING"]
    assert "written again" in caplog.records[1].getMessage()


def test_a_statements_own_fault_is_not_the_files(store):
    with pytest.raises(sqlite3.IntegrityError):
        store.add_stock_event(t=1.0, tank="T1", kind="mortality", count=0, to_tank=None, who="x")   # CHECK
    with pytest.raises(RuntimeError, match="not an open intent"):
        store.close_feed("nope", "done", 1.0, 2.0)
    assert store.unwritable is None and not store.db.in_transaction


def test_alarms_stand_and_are_published_while_the_ledger_is_full_and_written_after(store):
    published = []
    alarms = Alarms(store, lambda suffix, payload, reliable=False: published.append((suffix, payload)),
                    ManualClock())
    with disk_full(store) as free:
        assert alarms.raise_("rail", "drive fault", "critical", kind="fault") is True
        assert ("rail", "fault") in alarms.active and published[-1][0] == "alarm/rail"
        assert alarms.clear("rail", kind="fault") and published[-1][1]["active"] is False
        assert alarms.raise_("rail", "drive fault again", "critical", kind="fault")
        assert alarms.flush() is False                   # still full: nothing written, nothing lost
        assert store.alarm_states() == []
        free()
        assert alarms.flush() is True
    [row] = store.alarm_states()
    assert (row["source"], row["kind"], row["active"], row["text"]) == ("rail", "fault", 1, "drive fault again")
    assert [tuple(r) for r in store.db.execute("SELECT source, kind, active FROM alarm")] == [("rail", "fault", 1)]
    restarted = Alarms(store, lambda *a, **k: None, ManualClock())
    assert ("rail", "fault") in restarted.active


def test_todays_ration_shows_while_the_ledger_is_full_and_is_written_after(tmp_path):
    farm = Farm(Store(tmp_path / "ledger.db"))
    now = farm.clock.now()
    with disk_full(farm.store) as free:
        shown = farm.rations.today("T1", now)
        assert shown.grams > 0 and farm.store.ration("T1", shown.date) is None
        assert farm.rations.payload("T1", now)["grams"] == pytest.approx(shown.grams, abs=0.01)
        free()
        again = farm.rations.today("T1", now)
    assert again == shown and farm.store.ration("T1", shown.date)["grams"] == shown.grams
    farm.store.close()


def test_an_override_is_refused_naming_the_ledger_and_its_audit_waits_for_it(tmp_path):
    farm = Farm(Store(tmp_path / "ledger.db"))
    overrides = Overrides(farm)

    async def send(command, payload):
        reply = await overrides.apply(command, payload)
        await asyncio.sleep(0)                 # the audit's flush, just after the reply
        return reply

    async def go():
        with disk_full(farm.store) as free:
            reply = await send("mortality", {"tank": "T1", "count": 5, "operator": "ana"})
            assert reply == {"ok": False, "error": f"ledger: cannot be written ({CAUSE}); try again once it can"}
            assert (await send("pause", {"tank": "T1"}))["ok"] is False
            assert farm.store.audit() == [] and farm.store.stock_events() == []
            free()
            overrides.flush_audit()
        assert [(r["command"], r["ok"]) for r in farm.store.audit()] == [("mortality", 0), ("pause", 0)]
    asyncio.run(go())
    farm.store.close()


def test_the_ledger_alarm_is_raised_once_and_cleared_once_it_is_written_again(store):
    published = []
    parts = SimpleNamespace(store=store, alarms=Alarms(store, lambda s, p, reliable=False: published.append(p),
                                                       ManualClock()),
                            overrides=SimpleNamespace(flush_audit=lambda: published.append("audit flushed")))
    watch = lambda: Controller._watch_ledger(parts)      # noqa: E731
    watch()
    assert published == []
    with disk_full(store) as free:
        with pytest.raises(LedgerUnwritable):
            big_write(store)
        for _ in range(3):
            watch()
        [alarm] = parts.alarms.active.of("ledger")
        assert alarm.kind == "unwritable" and alarm.severity == "critical" and CAUSE in alarm.text
        assert [p["active"] for p in published] == [True]
        free()
        watch()
    assert ("ledger", "unwritable") not in parts.alarms.active
    assert [p if isinstance(p, str) else p["active"] for p in published] == [True, "audit flushed", False]
    history = [tuple(r) for r in store.db.execute("SELECT kind, active FROM alarm WHERE source = 'ledger'")]
    assert history == [("unwritable", 1), ("unwritable", 0)]


def test_the_feeder_feeds_nothing_until_the_ledger_takes_its_intent_then_serves_once(tmp_path):
    async def main():
        async with rig(tmp_path) as r:
            await r.until(lambda: r.robot.state == "idle")
            r.rations.today("T1", r.clock.now())           # the day's ration written before
            demand = r.demand("T1")                         # nothing runs before the disk is full
            with disk_full(r.store) as free:
                await r.until(lambda: r.robot.state == "fault", what="feeder fault on the intent")
                await r.clock.asleep(10.0)                     # retries, still full
                assert r.sim.physics.runs == [] and r.delivered == {}
                assert r.store.db.execute("SELECT COUNT(*) FROM feed").fetchone()[0] == 0
                free()
                await r.until(lambda: r.store.db.execute("SELECT outcome FROM demand WHERE id = ?", (demand,))
                              .fetchone()[0] == "served", what="the demand served once the ledger takes writes")
            await r.until(lambda: r.robot.state == "idle")
            [run] = r.sim.physics.runs
            [feed] = r.store.db.execute("SELECT * FROM feed").fetchall()
            assert feed["phase"] == "done" and feed["tag"] == run.tag
    asyncio.run(asyncio.wait_for(main(), 60))
