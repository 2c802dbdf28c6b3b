import contextlib
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from controller.errors import BadInput
from controller.feed_outcome import next_tag, reconcile
from controller.store import MIGRATIONS, Store
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


def intent(store, tank="T1", cycles=10, target=50.0, date="2026-06-01", hopper=None, device_tags=()):
    return store.add_intent(tank=tank, date=date, t=100.0, target_g=target, run_s=4.0,
                            cycles_before=cycles, source="demand", hopper_before=hopper, device_tags=device_tags)


def test_wal_and_full_sync(store):
    assert store.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert store.db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    assert store.schema_version == len(MIGRATIONS)


def test_newer_schema_is_refused(tmp_path):
    path = tmp_path / "x.db"
    db = sqlite3.connect(path)
    db.execute(f"PRAGMA user_version = {len(MIGRATIONS) + 1}")
    db.close()
    with pytest.raises(BadInput) as exc:           # bad input (exit 2), not an internal error (exit 1)
        Store(path)
    assert str(exc.value) == (f"store.path: {path}: ledger schema {len(MIGRATIONS) + 1}, this program reads "
                              f"{len(MIGRATIONS)}: a newer program wrote it")


HOLDER = textwrap.dedent("""
    import sys
    from controller.store import Store
    Store(sys.argv[1]).claim()
    print("held", flush=True)
    sys.stdin.read()
""")


@contextlib.contextmanager
def held_by_another(path):
    """The ledger at ``path`` claimed by another process (its pid), SIGKILLed at the end."""
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(path)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        yield holder.pid
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(10)


def test_one_controller_per_ledger_and_a_killed_ones_claim_goes_with_it(tmp_path):
    """A second controller on a ledger settled the first's feed in flight as suspect, and the first,
    resuming, served that feed again: two auger runs for one request."""
    path = tmp_path / "ledger.db"
    with held_by_another(path) as pid:
        second = Store(path)
        with pytest.raises(BadInput) as exc:
            second.claim()
        assert str(exc.value) == (f"store.path: {path}: another controller (pid {pid}) runs on this "
                                  "ledger: one controller per ledger")
        assert second.db is None                      # refused: nothing of it left open
        reader = Store(path)                          # a survey or report beside it still opens the ledger
        reader.close()
    mine = Store(path)
    mine.claim()                                      # the kernel dropped the killed one's lock
    mine.claim()                                      # twice is one claim
    mine.close()
    mine.close()
    again = Store(path)
    again.claim()                                     # closing let it go
    again.close()


@pytest.mark.parametrize("how", ["symlink", "symlinked directory", "relative with dots"])
def test_the_same_ledger_by_another_name_is_the_same_ledger(tmp_path, how):
    """Reached through a symlink, the ledger was claimed beside the link's name: two controllers
    ran on one ledger, each holding its own lock."""
    (tmp_path / "real").mkdir()
    path = tmp_path / "real" / "ledger.db"
    other = {"symlink": tmp_path / "link.db", "symlinked directory": tmp_path / "alias" / "ledger.db",
             "relative with dots": tmp_path / "real" / ".." / "real" / "ledger.db"}[how]
    if how == "symlink":
        other.symlink_to(path)
    elif how == "symlinked directory":
        (tmp_path / "alias").symlink_to(tmp_path / "real")
    with held_by_another(path) as pid:
        second = Store(other)
        with pytest.raises(BadInput) as exc:
            second.claim()
        assert f"another controller (pid {pid}) runs on this ledger" in str(exc.value)


CHILD = textwrap.dedent("""
    import sys
    from controller.store import Store
    store = Store(sys.argv[1])
    n = 0
    while True:
        d = store.add_demand("T1", float(n), 0.5)
        f = store.add_intent(tank="T1", date="2026-06-01", t=float(n), target_g=50.0, run_s=4.0,
                             cycles_before=n, source="demand", demand_id=d)
        # close and serve in one transaction: both or neither may survive a kill
        store.close_feed(f.id, "done", 49.0, float(n), served_demand=d)
        print(f.seq, flush=True)
        n += 1
""")


def test_a_process_killed_mid_transaction_leaves_a_consistent_ledger(tmp_path):
    """A real process commits intents in a loop (each fsynced) and is SIGKILLed at random points,
    three times over the same file; every commit it reported survives, nothing half-written does."""
    path = tmp_path / "l.db"
    reported = 0
    for round_, after in enumerate((40, 57, 83)):
        child = subprocess.Popen([sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True,
                                 cwd=os.path.dirname(os.path.dirname(os.path.dirname(__file__))))
        lines = 0
        for line in child.stdout:                 # committed: the child printed after COMMIT returned
            reported = max(reported, int(line))
            lines += 1
            if lines >= after:
                break
        child.send_signal(signal.SIGKILL)         # mid-loop: most of its time is spent in a commit
        child.wait(10)
        for line in child.stdout:                 # what it committed and said before the kill landed
            reported = max(reported, int(line))   # (a loaded machine delivers the signal late)
        child.stdout.close()
        assert child.returncode == -signal.SIGKILL
        s = Store(path)
        try:
            assert s.db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
            seqs = [f.seq for f in s.feeds()]
            assert seqs == list(range(1, len(seqs) + 1))          # no gap, no duplicate
            assert reported <= len(seqs) <= reported + 1, (round_, reported, len(seqs))   # one in flight
            demands = {r["id"]: r for r in s.db.execute("SELECT * FROM demand")}
            for f in s.feeds():
                d = demands[f.demand_id]
                # the close and the serving are one transaction: both or neither
                assert (f.phase == "done") == (d["outcome"] == "served"), (f, dict(d))
                if f.phase == "done":
                    assert d["feed_id"] == f.id and f.grams == 49.0
            # each kill may leave one demand whose intent never committed and one intent never closed
            orphans = set(demands) - {f.demand_id for f in s.feeds()}
            assert len(orphans) <= round_ + 1 and all(demands[d]["outcome"] == "open" for d in orphans)
            assert len(s.open_intents()) <= round_ + 1
        finally:
            s.close()
    assert reported >= 40 + 57 + 83 - 3


def test_intent_survives_reopen_and_closes_once(tmp_path):
    s = Store(tmp_path / "l.db")
    f = intent(s)
    s.close()
    s = Store(tmp_path / "l.db")
    [open_] = s.open_intents()
    assert open_.id == f.id and open_.phase == "intent" and open_.cycles_before == 10
    s.close_feed(f.id, "done", 49.3, 105.0)
    with pytest.raises(RuntimeError):
        s.close_feed(f.id, "done", 49.3, 105.0)      # never twice
    assert s.fed_g("T1", "2026-06-01") == pytest.approx(49.3)
    assert s.open_intents() == []
    s.close()


def test_a_version_1_ledger_is_migrated_in_place(tmp_path):
    path = tmp_path / "old.db"
    db = sqlite3.connect(path)
    db.executescript(MIGRATIONS[0])
    db.execute("INSERT INTO feed (id, seq, tank, date, t_intent, target_g, run_s, tag, cycles_before, phase, "
               "source) VALUES ('a', 7, 'T1', '2026-06-01', 1.0, 40.0, 3.0, 7, 5, 'intent', 'demand')")
    db.execute("PRAGMA user_version = 1")
    db.commit()
    db.close()
    s = Store(path)
    try:
        assert s.schema_version == len(MIGRATIONS) == 11
        [f] = s.open_intents()
        assert (f.id, f.tag, f.hopper_before, f.settled_by) == ("a", 7, None, None)
        assert intent(s).tag == 8 and intent(s).seq == 9          # the sequence goes on
        assert s.counters_seen("d") is None
    finally:
        s.close()


@pytest.mark.parametrize("version", range(1, len(MIGRATIONS) + 2))
def test_a_reader_takes_a_ledger_as_it_is_from_reads_from_on_and_names_the_others(tmp_path, version):
    """``report``/``history`` read without writing: a ledger at schema 10 (11 only added columns no
    reader reads) is read as it is; older ones need the controller's migration first, said so."""
    from controller.errors import BadInput
    from controller.store import READS_FROM
    path = tmp_path / "old.db"
    db = sqlite3.connect(path)
    for step in MIGRATIONS[:min(version, len(MIGRATIONS))]:
        db.executescript(step)
    db.execute(f"PRAGMA user_version = {version}")
    db.commit()
    db.close()
    if READS_FROM <= version <= len(MIGRATIONS):
        s = Store.reader(path)
        try:
            assert s.surveys("T1") == [] and s.fed_g("T1", "2026-06-01") == 0
        finally:
            s.close()
    else:
        with pytest.raises(BadInput, match="start the controller once" if version < READS_FROM else "newer"):
            Store.reader(path)
    assert READS_FROM == 10 == len(MIGRATIONS) - 1     # raise it with a migration that changes what readers read


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


def test_reconcile_someone_elses_run_is_suspect(store):
    f = intent(store, cycles=10)
    r = reconcile(f, state(cycles=11, last_tag=(f.tag % 65535) + 1))
    assert (r.phase, r.grams) == ("suspect", None)


def test_reconcile_counters_gone_backwards_is_suspect(store):
    f = intent(store, cycles=10, hopper=5000.0)
    # a power cut reset the PLC: even a LAST_TAG of ours after the reset is not taken on trust
    for s in (state(cycles=0, last_tag=0, hopper_g=4951.0), state(cycles=1, last_tag=f.tag, last_grams=49.0)):
        r = reconcile(f, s)
        assert (r.phase, r.grams) == ("suspect", None) and "backwards" in r.note
    assert "49.0 g down" in reconcile(f, state(cycles=0, hopper_g=4951.0)).note


def test_reconcile_food_gone_with_no_run_counted_is_suspect(store):
    f = intent(store, cycles=7, hopper=5000.0)
    assert reconcile(f, state(cycles=7, hopper_g=4990.0)).phase == "suspect"
    assert reconcile(f, state(cycles=7, hopper_g=4999.9)).phase == "aborted"    # one count of jitter
    assert reconcile(f, state(cycles=7, hopper_g=5000.0)).phase == "aborted"


@pytest.mark.parametrize("hopper_now", [4990.0, 5000.0, 6000.0])
def test_reconcile_from_a_count_of_0_to_0_is_suspect_whatever_the_load_cell(store, hopper_now):
    """0 -> 0 is also a run then a power-on (a power cut, a new PLC, a simulator started anew with
    the controller), and a refilled hopper hides the load cell's drop: never "aborted" from there."""
    f = intent(store, cycles=0, hopper=5000.0)
    r = reconcile(f, state(cycles=0, hopper_g=hopper_now))
    assert (r.phase, r.grams) == ("suspect", None)
    assert reconcile(f, state(cycles=1, last_tag=f.tag, last_grams=48.0)).phase == "done"   # counted: told


def test_reconcile_an_accepted_start_with_no_run_is_suspect(store):
    f = intent(store, cycles=10, hopper=5000.0)
    assert reconcile(f, state(cycles=10), accepted=True).phase == "suspect"
    assert reconcile(f, state(cycles=10, running=True, run_tag=f.tag), accepted=True).phase == "wait"


def test_suspect_stays_against_the_ration_until_settled(store):
    a, b, c = intent(store, target=40), intent(store, target=30), intent(store, target=20)
    store.mark_suspect(a.id, "counters went backwards")
    store.mark_suspect(b.id, "counters went backwards")
    store.close_feed(c.id, "done", 21.0, 1.0)
    with pytest.raises(RuntimeError):
        store.close_feed(a.id, "aborted", None, 1.0)           # not an open intent any more
    assert store.open_intents() == [] and [f.id for f in store.suspects()] == [a.id, b.id]
    assert store.committed_g("T1", "2026-06-01") == pytest.approx(40 + 30 + 21)
    assert store.fed_g("T1", "2026-06-01") == pytest.approx(21)
    done = store.settle_suspect(a.id, 38.5, 2.0, "ana", "weighed the tank's leftovers")
    assert (done.phase, done.grams, done.settled_by) == ("done", 38.5, "ana")
    assert "weighed" in done.note and "backwards" in done.note
    none = store.settle_suspect(b.id, 0, 2.0, "ana", "hopper was empty")
    assert (none.phase, none.grams) == ("aborted", None)
    assert store.committed_g("T1", "2026-06-01") == pytest.approx(38.5 + 21)
    with pytest.raises(LookupError):
        store.settle_suspect(a.id, 1.0, 3.0, "ana", "again")      # once only
    with pytest.raises(LookupError):
        store.settle_suspect("nope", 1.0, 3.0, "ana", "")


def test_tags_follow_the_ledger_and_skip_what_the_device_shows(store):
    assert [intent(store).tag for _ in range(3)] == [1, 2, 3]
    assert intent(store, device_tags=(4, 0)).tag == 5
    assert intent(store, device_tags=(6, 7)).tag == 8


def test_tags_wrap_from_65535_to_1_skipping_0():
    assert next_tag(65534) == 65535
    assert next_tag(65535) == 1
    assert next_tag(65535, (1, 0)) == 2
    assert next_tag(65534, (65535, 1)) == 2
    assert next_tag(None) == 1 and next_tag(0, (1,)) == 2


def test_tags_wrap_in_the_ledger(store):
    store.db.execute("INSERT INTO feed (id, seq, tank, date, t_intent, target_g, run_s, tag, cycles_before, "
                     "phase, source) VALUES ('w', 70000, 'T1', 'd', 1, 1, 1, 65535, 0, 'done', 'demand')")
    f = intent(store, device_tags=(65535, 0))
    assert (f.seq, f.tag) == (70001, 1)
    assert intent(store, device_tags=(1, 2)).tag == 3


def test_a_lost_ledger_does_not_reuse_the_tag_the_device_remembers(tmp_path):
    s = Store(tmp_path / "new.db")        # the old ledger is gone; the device last ran tag 1
    try:
        assert intent(s, device_tags=(1, 0)).tag == 2
    finally:
        s.close()


def test_counters_seen_are_remembered(tmp_path):
    s = Store(tmp_path / "c.db")
    s.see_counters("dispenser", 12, 480.5, 1.0)
    s.see_counters("dispenser", 13, 520.0, 2.0)
    s.close()
    s = Store(tmp_path / "c.db")
    assert s.counters_seen("dispenser") == (13, 520.0)
    s.close()


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


def test_forgotten_counters_are_not_compared(tmp_path):
    s = Store(tmp_path / "l.db")
    try:
        s.see_counters("dispenser", 12, 340.5, 1.0)
        s.see_counters("other", 3, 10.0, 1.0)
        s.forget_counters("dispenser")
        assert s.counters_seen("dispenser") is None and s.counters_seen("other") == (3, 10.0)
    finally:
        s.close()


FULL = textwrap.dedent("""
    import resource, signal, sys
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)      # a write past the limit fails, as on a full disk
    resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536))
    from controller.errors import BadInput
    from controller.store import Store
    try:
        Store(sys.argv[1])
    except BadInput as exc:
        print(exc)
""")


def test_a_ledger_the_disk_cannot_hold_says_so_not_cannot_rollback(tmp_path):
    """A full disk at start said 'cannot rollback - no transaction is active': SQLite had rolled
    the migration back itself, and our ROLLBACK's error hid the cause."""
    path = tmp_path / "ledger.db"
    out = subprocess.run([sys.executable, "-c", FULL, str(path)], capture_output=True, text=True, timeout=60)
    said = out.stdout.strip()
    assert said.startswith(f"store.path: {path}: cannot open the ledger: "), out
    assert "rollback" not in said and ("disk" in said or "full" in said), said


READER = textwrap.dedent("""
    import sys
    from controller.errors import BadInput
    from controller.store import Store, ledger_time
    try:
        s = Store.reader(sys.argv[1])
    except BadInput as exc:
        print("refused:", exc)
    else:
        print("surveys", s.db.execute("SELECT COUNT(*) FROM survey").fetchone()[0], "latest", ledger_time(sys.argv[1]))
        s.close()
""")


def _as_another_user(cmd: list[str]) -> list[str]:
    """``cmd`` as a user who may not write where the ledger is: root stripped of the capabilities
    that let it write anywhere (the directory is then another user's)."""
    if os.geteuid() != 0:
        return cmd
    import shutil
    if shutil.which("setpriv") is None:
        pytest.skip("root, and no setpriv to drop its capabilities")
    return ["setpriv", "--inh-caps", "-all", "--bounding-set", "-all", "--", *cmd]


@pytest.mark.parametrize("left", ["nothing", "a write-ahead log"])
def test_a_ledger_in_a_directory_the_reader_cannot_write_is_read(tmp_path, left):
    """The controller a service user, an operator reading: a WAL ledger is read through its -shm
    index, which SQLite creates beside it, and after a clean stop (which removes -wal and -shm) the
    readers failed: 'attempt to write a readonly database'. The file alone is read as it stands;
    with a write-ahead log left beside it (a controller killed), the refusal says why."""
    import tempfile
    place = Path(tempfile.mkdtemp(prefix="fishfarm-ro-"))
    try:
        path = place / "ledger.db"
        s = Store(path)
        s.add_survey("T1", 1_780_000_000.0, "sparus_aurata", "a", [12.0] * 3, [20.0] * 3)
        s.close()
        if left != "nothing":
            keep = Store(path)                          # a writer's WAL, left as a killed controller leaves it
            keep.add_survey("T1", 1_780_100_000.0, "sparus_aurata", "b", [13.0] * 3, [25.0] * 3)
            import shutil
            for end in ("-wal", "-shm"):
                shutil.copy(f"{path}{end}", f"{path}{end}.keep")
            keep.close()
            for end in ("-wal", "-shm"):
                os.rename(f"{path}{end}.keep", f"{path}{end}")
            os.remove(f"{path}-shm")                    # the index is the reader's to make, and it cannot
        assert not Path(f"{path}-shm").exists()
        if os.geteuid() == 0:
            for p in (place, *place.iterdir()):
                os.chown(p, 65534, 65534)
        place.chmod(0o555)
        r = subprocess.run(_as_another_user([sys.executable, "-c", READER, str(path)]), capture_output=True,
                           text=True, timeout=60, cwd=str(Path(__file__).resolve().parents[2]))
        if left == "nothing":
            # ... and the latest time it records, which a --since duration is measured back from
            assert r.stdout.strip() == "surveys 1 latest 1780000000.0", (r.stdout, r.stderr)
        else:
            assert "write-ahead log is beside it" in r.stdout and "not writable for this user" in r.stdout, r
        assert sorted(p.name for p in place.iterdir()) == sorted(
            ["ledger.db"] + (["ledger.db-wal"] if left != "nothing" else []))
    finally:
        place.chmod(0o700)
        import shutil
        shutil.rmtree(place, ignore_errors=True)


def test_another_program_s_database_is_refused_and_left_as_it_was(tmp_path):
    """A file of another program's tables (user_version 0, tables in it) was taken for a new ledger:
    the controller added its 15 tables beside the customers and ran on it."""
    path = tmp_path / "shop.db"
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE customers (id INTEGER PRIMARY KEY, name TEXT)")
    db.commit()
    db.close()
    before = path.read_bytes()
    with pytest.raises(BadInput) as exc:
        Store(path)
    assert str(exc.value) == f"store.path: {path}: not a fishfarm ledger: another program's database (tables customers)"
    assert path.read_bytes() == before
    empty = tmp_path / "empty.db"
    empty.write_bytes(b"")
    Store(empty).close()                        # an empty file is a new ledger, as a missing one


@pytest.mark.parametrize("table", ["tank_pause", "feed"])
def test_a_ledger_missing_a_table_is_refused_at_open_naming_it(tmp_path, table):
    """A ledger of the current schema with a table dropped by hand failed mid-run, as an internal
    error, after the simulator and the SCADA server had started."""
    path = tmp_path / "ledger.db"
    Store(path).close()
    db = sqlite3.connect(path)
    db.execute(f"DROP TABLE {table}")
    db.commit()
    db.close()
    with pytest.raises(BadInput) as exc:
        Store(path)
    assert str(exc.value) == f"store.path: {path}: ledger damaged: table {table} missing"


FILL = textwrap.dedent("""
    import resource, sys
    from controller.ledger_writes import LedgerUnwritable
    from controller.store import Store
    s = Store(sys.argv[1])
    resource.setrlimit(resource.RLIMIT_FSIZE, (400_000, resource.RLIM_INFINITY))
    try:
        for i in range(10_000):
            s.add_survey("T1", 1_780_000_000.0 + i, "sparus_aurata", "x" * 200, [12.0] * 50, [20.0] * 50)
    except LedgerUnwritable as exc:
        print("unwritable:", exc)
""")


def test_a_file_size_limit_is_named_as_the_cause(tmp_path):
    """Under `ulimit -f` the ledger's writes failed as "disk I/O error" (Python ignores SIGXFSZ),
    nothing saying it was the process's file-size limit."""
    r = subprocess.run([sys.executable, "-c", FILL, str(tmp_path / "ledger.db")], capture_output=True, text=True,
                       timeout=120, cwd=str(Path(__file__).resolve().parents[2]))
    assert r.stdout.startswith("unwritable:") and "ulimit -f: 400000 bytes" in r.stdout, (r.stdout, r.stderr)
