"""The HIL evidence itself can fail: the ledger is judged run by run, every problem counted."""
from hil_tests.evidence import Verdict, ledger_against_runs, service_against_demands


def feed(id_, tag, t, phase="done", grams=40.0, **kw):
    return {"id": id_, "seq": int(t * 1000), "tag": tag, "tank": "T1", "t_intent": t, "phase": phase,
            "grams": grams, "settled_by": None, **kw}


def run(tag, t, physical=40.03, measured=40.0, **kw):
    return {"kind": "auger_run", "tag": tag, "t_start": t + 0.5, "t": t + 4.0, "physical_g": physical,
            "measured_g": measured, "jammed": False, **kw}


def judged(feeds, runs):
    v = Verdict()
    ledger_against_runs(v, feeds, runs)
    return v


def test_a_clean_ledger_passes():
    v = judged([feed("a", 1, 10.0), feed("b", 2, 20.0), feed("c", 3, 30.0, phase="aborted", grams=None)],
               [run(1, 10.0), run(2, 20.0)])
    assert v.problems == [] and v.runs_compared == 2


def test_one_lost_run_plus_one_repeated_run_fail_though_the_totals_agree():
    # tag 2's run went unrecorded, tag 1 ran twice: two rows, two runs, same grams in total
    v = judged([feed("a", 1, 10.0), feed("b", 2, 20.0, phase="aborted", grams=None)],
               [run(1, 10.0), run(1, 10.2), run(2, 20.0)])
    assert abs(v.ledger_g - 40.0) < 1e-9
    assert len(v.problems) == 2, v.problems
    assert any("matches 2 auger runs" in p for p in v.problems)
    assert any("booked without grams" in p for p in v.problems)


def test_every_problem_is_counted_past_forty():
    v = judged([], [run(t, 10.0 * t) for t in range(1, 101)])
    assert len(v.problems) == 100 and all("has no ledger row" in p for p in v.problems)


def test_a_done_row_without_a_physical_run_fails():
    v = judged([feed("a", 1, 10.0), feed("b", 2, 20.0)], [run(1, 10.0)])
    assert len(v.problems) == 1 and "never gave" in v.problems[0]


def test_grams_beyond_the_load_cells_resolution_fail():
    v = judged([feed("a", 1, 10.0, grams=40.0)], [run(1, 10.0, physical=40.25, measured=40.0)])
    assert len(v.problems) == 2          # the load cell against physics, the ledger against physics


def test_a_reused_tag_is_matched_by_time():
    v = judged([feed("a", 7, 10.0), feed("b", 7, 500.0)], [run(7, 10.0), run(7, 500.0)])
    assert v.problems == []
    v = judged([feed("a", 7, 10.0), feed("b", 7, 500.0)], [run(7, 500.0)])
    assert len(v.problems) == 1 and "feed a" in v.problems[0]


def test_a_power_cut_run_must_be_held_as_suspect():
    cut = run(4, 40.0, physical=17.2, measured=None, power_cut=True)
    assert judged([feed("d", 4, 40.0, phase="suspect", grams=None)], [cut]).problems == []
    v = judged([feed("d", 4, 40.0, phase="aborted", grams=None)], [cut])
    assert len(v.problems) == 1 and "does not know" in v.problems[0]
    assert len(judged([feed("d", 4, 40.0, phase="intent", grams=None), feed("e", 5, 50.0, phase="aborted")],
                      [cut]).problems) == 1
    # an operator's settlement is held to the physics within the resolution
    assert judged([feed("d", 4, 40.0, grams=17.2, settled_by="ana")], [cut]).problems == []
    assert len(judged([feed("d", 4, 40.0, grams=30.0, settled_by="ana")], [cut]).problems) == 1


def test_a_run_that_started_long_after_its_intent_is_still_its_own():
    # a loaded machine at 1440x: 0.2 s of wall between intent and START is 288 farm s
    assert judged([feed("a", 1, 10.0)], [run(1, 300.0)]).problems == []
    # ... but a run never belongs to an intent that came after it
    assert len(judged([feed("a", 1, 10.0)], [run(1, 5.0)]).problems) == 2


def test_only_the_latest_intent_may_be_open_at_the_end():
    # the controller stopped during the last run: it settles that intent when it starts again
    assert judged([feed("a", 1, 10.0), feed("b", 2, 20.0, phase="intent", grams=None)],
                  [run(1, 10.0), run(2, 20.0)]).problems == []
    v = judged([feed("a", 1, 10.0, phase="intent", grams=None), feed("b", 2, 20.0)], [run(1, 10.0), run(2, 20.0)])
    assert len(v.problems) == 1 and "left open" in v.problems[0]


def test_late_service_is_a_queue_only_behind_other_tanks():
    demand_t = {1: 0.0, 2: 1.0, 3: 2.0, 4: 500.0, 5: 900.0}
    feeds = [feed("a", 1, 12.0, demand_id=1), feed("b", 2, 35.0, demand_id=2),
             feed("c", 3, 64.0, demand_id=3),            # behind a and b: the robot never idled
             feed("d", 4, 575.0, demand_id=4),           # 75 s with nothing else served: a lapse
             feed("e", 5, 905.0, demand_id=5)]
    v = Verdict()
    service_against_demands(v, feeds, demand_t)
    assert len(v.queued) == 1 and "feed c" in v.queued[0]
    assert len(v.problems) == 1 and "feed d" in v.problems[0]
    v = Verdict()
    service_against_demands(v, feeds, demand_t, since=600.0)   # the warm-up's raises are not judged
    assert v.queued == [] and v.problems == [] and v.service_s == [5.0]


def test_a_feed_under_way_when_the_demand_is_raised_counts_in_the_queue():
    demand_t = {1: 0.0, 2: 10.0, 3: 20.0, 4: 300.0, 5: 400.0}
    feeds = [feed("a", 1, 5.0, demand_id=1, t_closed=25.0),   # serving a when 3 is raised
             feed("b", 2, 40.0, demand_id=2, t_closed=55.0),
             feed("c", 3, 85.0, demand_id=3, t_closed=95.0),  # 65 s behind a (running) and b
             feed("d", 4, 301.0, demand_id=4, t_closed=310.0),  # closed before 5 was raised
             feed("e", 5, 470.0, demand_id=5, t_closed=480.0)]  # 70 s, the robot idle: a lapse
    v = Verdict()
    service_against_demands(v, feeds, demand_t)
    assert len(v.queued) == 1 and "feed c" in v.queued[0] and "behind 2 other feeds" in v.queued[0]
    assert len(v.problems) == 1 and "feed e" in v.problems[0]


def test_the_warm_up_is_not_judged():
    demand_t = {1: 0.0, 2: 1.0, 3: 2.0, 4: 500.0, 5: 900.0}
    feeds = [feed("e", 5, 905.0, demand_id=5)]
    v = Verdict()
    service_against_demands(v, feeds, demand_t, since=600.0)
    assert v.queued == [] and v.problems == [] and v.service_s == [5.0]


def test_lateness_is_excused_only_by_the_time_the_machine_stood_still():
    demands = {"d1": 100.0, "d2": 1000.0, "d3": 2000.0}
    feeds = [feed("a", 1, 100.0 + 150.0, demand_id="d1"),      # 150 s, 100 of them stalled: 50 s
             feed("b", 2, 1000.0 + 150.0, demand_id="d2"),     # 150 s, 80 stalled: still 70 s late
             feed("c", 3, 2000.0 + 150.0, demand_id="d3")]     # 150 s, the stall after it was served
    stalls = [(120.0, 220.0), (1050.0, 1130.0), (2200.0, 2400.0)]
    v = Verdict()
    service_against_demands(v, feeds, demands, stalls=stalls)
    assert len(v.stalled) == 1 and "feed a" in v.stalled[0]
    assert len(v.problems) == 2 and {p.split()[1] for p in v.problems} == {"b", "c"}


def test_the_witness_records_a_stop():
    import sys
    import time

    from hil_tests.stalls import StallWitness, stalled_s
    w = StallWitness(threshold_s=0.2).start()
    time.sleep(0.3)                                  # the witness wakes every 5 ms meanwhile
    before = list(w.spans)
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1.0)                       # this thread keeps the interpreter 0.5 s:
    try:                                             # the witness cannot run, as in a stall
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            pass
    finally:
        sys.setswitchinterval(interval)
    time.sleep(0.05)
    w.stop()
    held = [s for s in w.spans if s not in before]   # (a real stall may have come before: kept apart)
    assert len(held) == 1
    (a, b), = w.farm_spans(epoch_wall=held[0][0], epoch_farm=1000.0, speed=360.0)[-1:]
    assert a == 1000.0 and 0.4 * 360 < b - a < 2.0 * 360
    assert stalled_s([(a, b)], a - 10, a + 10) == 10.0


def test_an_open_demand_heard_just_before_the_end_is_sorted_out_one_left_unserved_is_not():
    """A slow fish's demand is dated back to its first contact (an hour before it was heard): one
    heard 36 s before the run's end was "never served (open)" and failed the 14-day grow-out."""
    import sqlite3

    from hil_tests.growout import sort_problems
    db = sqlite3.connect(":memory:")
    db.execute("CREATE TABLE farm_clock (id INTEGER PRIMARY KEY, t REAL NOT NULL)")
    db.execute("INSERT INTO farm_clock VALUES (1, 100000.0)")
    heard = [("T7", 95600.0, 4364.0), ("T2", 90000.0, 30.0)]
    out = sort_problems(db, ["demand 590 for T7 at 95600.0 never served (open)",
                             "demand 12 for T2 at 90000.0 never served (open)"], heard, 70.0)
    assert out["heard_late"] == 1 and out["problems"] == ["demand 12 for T2 at 90000.0 never served (open)"]


def test_a_demand_for_fish_asking_since_before_the_warm_up_is_no_false_demand():
    """A tank whose fish began asking while the controller came up is fed on its backlog: that
    demand lies in a real episode (it was called false, and failed the farm day one run in ten);
    the episode itself is not judged for how soon its demand came. A demand outside every episode
    still is false, before the warm-up's end or after it."""
    import sqlite3

    from hil_tests.evidence import judge
    db = sqlite3.connect(":memory:")
    db.row_factory = sqlite3.Row
    db.execute("CREATE TABLE demand (id INTEGER PRIMARY KEY, tank TEXT, t REAL, outcome TEXT, source TEXT)")
    db.execute("CREATE TABLE feed (seq INTEGER, id TEXT, tag INTEGER, tank TEXT, t_intent REAL, phase TEXT,"
               " grams REAL, settled_by TEXT, demand_id INTEGER, date TEXT)")
    db.execute("CREATE TABLE ration (tank TEXT, date TEXT, grams REAL)")
    db.executemany("INSERT INTO demand VALUES (?, ?, ?, 'fed', 'demand')",
                   [(1, "T1", 150.0), (2, "T1", 400.0), (3, "T2", 160.0), (4, "T2", 1300.0)])
    truth = [{"kind": "episode_start", "t": 100.0, "tank": "T1"},      # before the warm-up's end (300)
             {"kind": "episode_end", "t": 500.0, "tank": "T1"},
             {"kind": "episode_start", "t": 1000.0, "tank": "T2"},     # after it: judged
             {"kind": "episode_end", "t": 1400.0, "tank": "T2"}]
    v = judge(db, truth, 2000.0, since=300.0)
    assert v.false_demands == ["demand 3 for T2 at 160.0 lies outside every episode"]
    assert v.episodes == 1 and v.detection_s == [300.0]
