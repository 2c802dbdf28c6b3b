import os
import sqlite3

import pytest

from controller.store import MIGRATIONS, Store, reconcile
from devices.dispenser import DispenserState


def state(**kw):
    base = dict(hopper_g=5000.0, running=False, jammed=False, refilling=False, cycles=10, last_tag=0,
                last_grams=0.0, total_grams=0.0, resolution_g=0.1)
    base.update(kw)
    return DispenserState(**base)


@pytest.fixture
def store(tmp_path):
    s = Store(tmp_path / "ledger.db")
    yield s
    s.close()


def intent(store, tank="T1", cycles=10, target=50.0, date="2026-06-01"):
    return store.add_intent(tank=tank, date=date, t=100.0, target_g=target, run_s=4.0,
                            cycles_before=cycles, source="demand")


def test_wal_and_full_sync(store):
    assert store.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert store.db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    assert store.schema_version == len(MIGRATIONS)


def test_newer_schema_is_refused(tmp_path):
    path = tmp_path / "x.db"
    db = sqlite3.connect(path)
    db.execute(f"PRAGMA user_version = {len(MIGRATIONS) + 1}")
    db.close()
    with pytest.raises(RuntimeError, match="newer"):
        Store(path)


def test_intent_survives_reopen_and_closes_once(tmp_path):
    s = Store(tmp_path / "l.db")
    f = intent(s)
    s.db.close()                       # as if the process died right after the commit
    s = Store(tmp_path / "l.db")
    [open_] = s.open_intents()
    assert open_.id == f.id and open_.phase == "intent" and open_.cycles_before == 10
    s.close_feed(f.id, "done", 49.3, 105.0)
    with pytest.raises(RuntimeError):
        s.close_feed(f.id, "done", 49.3, 105.0)      # never twice
    assert s.fed_g("T1", "2026-06-01") == pytest.approx(49.3)
    assert s.open_intents() == []


def test_tags_are_distinct_and_16_bit(store):
    tags = {intent(store).tag for _ in range(5)}
    assert len(tags) == 5 and all(0 < t < 65536 for t in tags)


def test_committed_counts_open_intents(store):
    a = intent(store, target=40)
    intent(store, target=30)
    store.close_feed(a.id, "done", 41.0, 1.0)
    assert store.committed_g("T1", "2026-06-01") == pytest.approx(71.0)
    assert store.fed_g("T1", "2026-06-01") == pytest.approx(41.0)
    assert store.committed_g("T1", "2026-06-02") == 0


def test_reconcile_run_completed(store):
    f = intent(store, cycles=10)
    r = reconcile(f, state(cycles=11, last_tag=f.tag, last_grams=48.7))
    assert (r.phase, r.grams) == ("done", 48.7)


def test_reconcile_never_started(store):
    f = intent(store, cycles=10)
    assert reconcile(f, state(cycles=10, last_tag=f.tag - 1)).phase == "aborted"


def test_reconcile_still_running_waits(store):
    f = intent(store, cycles=10)
    assert reconcile(f, state(cycles=10, running=True)).phase == "wait"


def test_reconcile_counter_wraps(store):
    f = intent(store, cycles=2**32 - 1)
    r = reconcile(f, state(cycles=0, last_tag=f.tag, last_grams=12.0))
    assert (r.phase, r.grams) == ("done", 12.0)


def test_reconcile_someone_elses_run_is_unknown(store):
    f = intent(store, cycles=10)
    assert reconcile(f, state(cycles=11, last_tag=(f.tag % 65535) + 1)).phase == "unknown"


def test_reconcile_jammed_run_counts_its_grams(store):
    f = intent(store, cycles=10)
    r = reconcile(f, state(cycles=11, last_tag=f.tag, last_grams=3.2, jammed=True))
    assert (r.phase, r.grams) == ("done", 3.2)


def test_alarms_latest_per_source(store):
    store.add_alarm("feeder", 1.0, "warning", "fault", True)
    store.add_alarm("feeder", 2.0, "warning", "ok", False)
    store.add_alarm("estop", 3.0, "critical", "stop", True)
    assert [r["source"] for r in store.active_alarms()] == ["estop"]


def test_ration_upsert(store):
    store.set_ration("T1", "2026-06-01", 1000.0, 2.0, "config", 1.0)
    store.set_ration("T1", "2026-06-01", 800.0, 2.0, "operator", 2.0)
    row = store.ration("T1", "2026-06-01")
    assert (row["grams"], row["source"]) == (800.0, "operator")


def test_unusable_path_is_bad_input_naming_store_path(tmp_path):
    from controller.errors import BadInput
    (tmp_path / "file").write_text("not a directory")
    (tmp_path / "junk.db").write_bytes(b"this is not SQLite" * 100)
    for path in (tmp_path / "file" / "x.db", tmp_path / "file" / "a" / "x.db", tmp_path, tmp_path / "junk.db"):
        with pytest.raises(BadInput) as exc:
            Store(path)
        assert str(exc.value).startswith(f"store.path: {path}: cannot open the ledger: ")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_directory_is_bad_input_naming_store_path(tmp_path):
    from controller.errors import BadInput
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        for path in (ro / "x.db", ro / "sub" / "x.db"):
            with pytest.raises(BadInput, match=r"^store\.path: "):
                Store(path)
    finally:
        ro.chmod(0o700)
