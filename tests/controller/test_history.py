"""A tank's history from the ledger: what the queryable serves and ``fishfarm history`` exports."""
from __future__ import annotations

import csv
import io

import pytest
import tomli_w

from controller.cli import main
from controller.config import load_config
from controller.errors import BadInput
from controller.history import history, iso, parse_time, query_reply
from controller.store import Store

T = 1_780_000_000.0                      # 2026-05-28T20:26:40Z
DAY = 86_400.0


@pytest.fixture
def ledger(tmp_path):
    store = Store(tmp_path / "ledger.db")
    store.add_survey("T1", T, "sparus_aurata", "a.json", [10.0, 12.0], [20.0, 30.0])
    store.add_survey("T1", T + 7 * DAY, "sparus_aurata", "b.json", [13.0], [40.0])
    store.add_survey("T2", T + DAY, "sparus_aurata", "c.json", [9.0], [10.0])
    store.add_stock_event(t=T + DAY, tank="T1", kind="mortality", count=3, to_tank=None, who="ana")
    store.add_stock_event(t=T + 2 * DAY, tank="T2", kind="transfer", count=50, to_tank="T1", who="ana")
    store.set_ration("T1", "2026-05-29", 500.0, 2.0, "survey", T + DAY)
    f = store.add_intent(tank="T1", date="2026-05-29", t=T + DAY, target_g=40, run_s=3, cycles_before=0,
                         source="demand")
    store.close_feed(f.id, "done", 41.5, T + DAY + 5)
    yield store
    store.close()


def test_each_kind_of_row_for_the_tank_oldest_first_within_the_range(ledger):
    cols, rows, more = history(ledger, "surveys", "T1")
    assert cols[:4] == ("time", "survey", "species", "count") and not more
    assert [r[0] for r in rows] == ["2026-05-28T20:26:40.000Z", "2026-06-04T20:26:40.000Z"]
    assert [r[3] for r in rows] == [2, 1]
    _, fish, _ = history(ledger, "fish", "T1", since=T + DAY)
    assert [(r[2], r[3]) for r in fish] == [(13.0, 40.0)]
    _, fish, _ = history(ledger, "fish", "T1", until=T)
    assert [(r[2], r[3]) for r in fish] == [(10.0, 20.0), (12.0, 30.0)]
    _, stock, _ = history(ledger, "stock", "T1")               # out of T1, and into it from T2
    assert [(r[1], r[2], r[3], r[4]) for r in stock] == [("mortality", 3, "T1", None), ("transfer", 50, "T2", "T1")]
    _, rations, _ = history(ledger, "rations", "T1")
    assert [r[1:] for r in rations] == [["2026-05-29", 500.0, 2.0, "survey"]]
    _, feeds, _ = history(ledger, "feeds", "T1")
    assert [(r[3], r[4], r[5]) for r in feeds] == [(40, 41.5, "done")]
    assert history(ledger, "feeds", "T3")[1] == []


@pytest.mark.parametrize(("text", "durations", "want"), [
    ("1780000000", False, T), ("2026-05-28T20:26:40", False, T), ("2026-05-28T22:26:40+02:00", False, T),
    ("2026-05-28T20:26:40Z", False, T), ("7d", True, T + 7 * DAY - 7 * DAY), ("36h", True, T - 1.5 * DAY),
    # eight digits alone are ISO's basic date, not seconds of 1970 (every row came back)
    ("20260528", False, T - (20 * 3600 + 26 * 60 + 40)), ("1780000000.5", False, T + 0.5),
    (1780000000, False, T), (1780000000.0, False, T), ("0", False, 0.0)])          # a JSON number: seconds
def test_times_are_iso_unix_seconds_or_a_span_back(text, durations, want):
    now = T + 7 * DAY if text == "7d" else T
    assert parse_time(text, "since", now, durations=durations) == pytest.approx(want)


@pytest.mark.parametrize("text", ["1" * 310, "1" * 5000, "9" * 400 + ".5", "1e400", "-1e400", "inf", "nan",
                                  "1" * 400 + "d",
                                  "\u0663", "1_000", "\u0661\u0662d",      # numbers Python reads, not ASCII
                                  "1e9", "+1796405848", "-5",                # not "ASCII digits"
                                  "2026120", 20261205, 20261205.0])          # before 2000: a date's typo
def test_a_number_no_float_holds_is_refused_not_read_as_a_date(text):
    """Python's fromisoformat reads '1111...' as 1111-11-11 (every row since then came back)."""
    with pytest.raises(BadInput, match="since"):
        parse_time(text, "since", T, durations=True)


@pytest.mark.parametrize(("text", "durations"), [
    ("1999-12-31", True), ("1999-12-31T23:59:59Z", False), ("2000-01-01T00:30:00+01:00", False),   # ISO
    ("19991231", True), ("1969-12-31", False), ("0001-01-01", True),                                # basic date, 1969
    (915_148_800, True), (915_148_800.5, False), ("915148800", True)])          # a JSON number, Unix seconds
def test_a_time_before_2000_is_refused_as_a_date_s_typo_in_every_form(text, durations):
    """README: "a time before 2000 other than 0 is refused as a date's typo" (only seconds were)."""
    with pytest.raises(BadInput, match=r"^since: .* is before 2000 \(a date's typo\?\)"):
        parse_time(text, "since", T, durations=durations)


@pytest.mark.parametrize("text", ["99999999d", "10000d", "1" * 300 + "w"])
def test_a_duration_reaching_back_before_2000_is_refused_in_one_line(text):
    with pytest.raises(BadInput, match=r"^since: .* reaches back before 2000") as refused:
        parse_time(text, "since", T, durations=True)
    assert "\n" not in str(refused.value)


@pytest.mark.parametrize(("text", "durations", "want"), [
    ("2000-01-01T00:00:00Z", False, 946_684_800.0), ("20000101", False, 946_684_800.0),
    ("1970-01-01T00:00:00Z", False, 0.0), (0, False, 0.0),                      # 0: "other than 0"
    ("9000d", True, T - 9000 * DAY)])                                            # 2001: after 2000
def test_times_from_2000_on_and_0_are_taken(text, durations, want):
    assert parse_time(text, "since", T, durations=durations) == pytest.approx(want)


def test_the_queryable_s_answers_and_refusals(ledger):
    cfg = load_config("config/farm.toml")
    reply = query_reply(ledger, cfg, "history/surveys/T1", {"since": "2026-06-01"}, T)
    assert reply["ok"] and len(reply["rows"]) == 1 and reply["columns"][0] == "time"
    for key, params, fault in [("history/surveys/T9", {}, "no tank 'T9'"),
                               ("history/weather/T1", {}, "'weather' is not one of surveys, fish"),
                               ("history/surveys/T1", {"from": "x"}, "unknown parameter 'from'"),
                               ("history/surveys/T1", {"since": "last tuesday"}, "since: 'last tuesday'"),
                               ("history/surveys/T1", {"until": "7d"}, "until: '7d' is not an ISO time"),
                               ("history/surveys/T1", {"since": "7d&until=1d"}, "separated by ';', not '&'"),
                               ("history/feeds/T1", {"since": "1999-12-31"}, "is before 2000 (a date's typo?)"),
                               ("history/feeds/T1", {"since": "99999999d"}, "reaches back before 2000"),
                               ("history/feeds/T1", {"until": 915148800}, "is before 2000 (a date's typo?)"),
                               ("history/feeds/T1", {"since": True}, "since: true: not a time"),  # was 'True'
                               ("history/feeds/T1", {"until": False}, "until: false: not a time"),
                               ("history/feeds/T1", {"since": None}, "since: null: not a time"),  # was 'None'
                               ("history/surveys/T1", {"since": "2027-01-01", "until": "2020-01-01"},
                                "since: 2027-01-01T00:00:00Z is after until (2020-01-01T00:00:00Z)")]:
        reply = query_reply(ledger, cfg, key, params, T)
        assert reply["ok"] is False and fault in reply["error"], (key, reply)


def test_fishfarm_history_writes_csv_with_units_in_the_headers(ledger, tmp_path, capsys):
    import tomllib
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    out = tmp_path / "fish.csv"
    cfg = str(tmp_path / "farm.toml")
    code = main(["history", "--tank", "T1", "--what", "fish", "--csv", str(out), "--config", cfg])
    assert code == 0 and "3 rows" in capsys.readouterr().err
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert [float(r["weight_g"]) for r in rows] == [20.0, 30.0, 40.0] and "length_cm" in rows[0]
    code = main(["history", "--tank", "T1", "--what", "surveys", "--since", "2026-06-01", "--config",
                 str(tmp_path / "farm.toml")])
    printed = capsys.readouterr().out.splitlines()
    assert code == 0 and len(printed) == 2 and printed[0].startswith("time,survey,species")
    code = main(["history", "--tank", "T1", "--what", "fish", "--since", "soon", "--config",
                 str(tmp_path / "farm.toml")])
    err = capsys.readouterr().err
    assert code == 2 and "--since: 'soon'" in err and err.count("\n") == 1
    code = main(["history", "--tank", "T1", "--what", "feeds", "--since", "1999-01-01", "--config", cfg])
    err = capsys.readouterr().err
    assert code == 2 and "--since: '1999-01-01'" in err and "before 2000" in err and err.count("\n") == 1


def test_a_range_given_in_both_the_selector_and_the_payload_is_refused(ledger):
    """The payload's won without a word: which one the asker meant is theirs to say."""
    import asyncio
    from types import SimpleNamespace

    from controller.overrides import Overrides
    c = SimpleNamespace(store=ledger, cfg=load_config("config/farm.toml"), clock=SimpleNamespace(now=lambda: T))
    ask = Overrides(c).history
    both = asyncio.run(ask({"since": "30d"}, key="history/surveys/T1", params={"since": "1d"}))
    assert both == {"ok": False, "error": "since: given in the selector and in the payload: give it once"}
    apart = asyncio.run(ask({"until": "2026-07-01"}, key="history/surveys/T1", params={"since": "2026-06-01"}))
    assert apart["ok"] and len(apart["rows"]) == 1


@pytest.fixture
def farm_toml(ledger, tmp_path):
    import tomllib
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    return str(tmp_path / "farm.toml")


# every form the README allows at its extremes: 0 = taken, else the option a one-line refusal names.
# audit takes ISO or a duration (any ISO date the calendar holds); history and report also Unix
# seconds, and none before 2000 but 0
EXTREMES = [
    ("--since", "99999999999999999w", {}), ("--since", "9999999999999d", {}), ("--since", "1" * 400 + "d", {}),
    ("--since", "0s", {"report": 0, "audit": 0, "history": 0}),
    ("--since", "0.000001s", {"report": 0, "audit": 0, "history": 0}),
    ("--since", "0001-01-01", {"audit": 0}), ("--since", "0001-01-01T00:00+01:00", {}),
    ("--since", "0001-01-01T00:00-23:59", {"audit": 0}),
    ("--since", "9999-12-31T23:59:59.99", {"report": 0, "audit": 0, "history": 0}),
    ("--since", "9999-12-31T23:00-05:00", {}), ("--since", "99991231", {"report": 0, "audit": 0, "history": 0}),
    ("--since", "99999999999999999999", {}), ("--since", "9" * 400, {}), ("--since", "253402300800", {}),
    ("--since", "253402300799", {"history": 0, "report": 0}),
    ("--until", "99999999999999999999", {}), ("--until", "253402300800", {}), ("--until", "9" * 400, {}),
    ("--until", "9999-12-31T23:00-05:00", {}), ("--until", "9999-12-31T23:59:59", {"history": 0}),
    ("--until", "253402300799.999", {"history": 0}),
    ("--since", "", {}), ("--until", "", {}), ("--since", "  ", {}),    # "" was no filter at all (exit 0)
]


@pytest.mark.parametrize("command", ["report", "audit", "history"])
@pytest.mark.parametrize(("option", "text", "taken"), EXTREMES)
def test_every_time_form_at_its_extremes_is_taken_or_refused_in_one_line(farm_toml, capsys, command, option,
                                                                            text, taken):
    """99999999999999999w, 9999999999999d and 1e20 s were an "internal error" (exit 1), an
    OverflowError or OSError from the date written for them."""
    if option == "--until" and command != "history":
        return
    args = {"report": ["report", "--tank", "T1"], "audit": ["audit"],
            "history": ["history", "--tank", "T1", "--what", "surveys"]}[command]
    if option == "--until":
        args = ["history", "--tank", "T1", "--what", "surveys", "--since", "2026-01-01"]
    code = main([*args, option, text, "--config", farm_toml])
    err = capsys.readouterr().err
    if command in taken:
        assert code == 0, err
    else:
        assert code == 2 and err.startswith(f"fishfarm: {option}: ") and err.count("\n") == 1, err


def test_a_since_beyond_the_calendar_before_an_until_is_refused_naming_since(farm_toml, capsys):
    """The refusal "since is after until" wrote a date for 1e20 s: OverflowError."""
    code = main(["history", "--tank", "T1", "--what", "fish", "--since", "99999999999999999999", "--until",
                 "2026-01-01", "--config", farm_toml])
    err = capsys.readouterr().err
    assert code == 2 and err == ("fishfarm: --since: '99999999999999999999' is after the year 9999: "
                                 "beyond the calendar\n")


@pytest.mark.parametrize(("params", "fault"), [
    ({"since": "99999999999999999999", "until": "2026-01-01"}, "since: '99999999999999999999' is after the year 9999"),
    ({"since": 1e20, "until": 1796400000}, "since: '1e+20' is after the year 9999"),
    ({"since": 10**400}, "since: an integer too big for a float"),
    ({"until": 10**5000}, "until: an integer too big for a float"),
    ({"until": 253402300800}, "until: '253402300800' is after the year 9999"),
    ({"since": "99999999999999999w"}, "since: '99999999999999999w' reaches back before 2000"),
    ({"until": "9999-12-31T23:00-05:00"}, "until: '9999-12-31T23:00-05:00' is after the year 9999")])
def test_the_queryable_refuses_a_time_beyond_the_calendar_naming_the_field(ledger, caplog, params, fault):
    """It answered "OverflowError: timestamp out of range for platform time_t" and logged a traceback."""
    cfg = load_config("config/farm.toml")
    reply = query_reply(ledger, cfg, "history/feeds/T1", params, T)
    assert reply == {"ok": False, "error": reply["error"]} and reply["error"].startswith(fault), reply
    assert "Traceback" not in caplog.text


def test_a_duration_is_measured_back_from_the_ledger_s_farm_time_when_it_runs_ahead(tmp_path, capsys):
    """A --speed 60 demo's ledger is days ahead of the wall clock: "--since 1h" back from the wall
    returned everything. Two of each, 2 h and 10 min before the ledger's latest entry."""
    import json
    import time
    import tomllib
    latest = time.time() + 3 * DAY
    store = Store(tmp_path / "ledger.db")
    for ago in (2 * 3600, 600):
        store.add_survey("T1", latest - ago, "sparus_aurata", f"{ago}", [10.0] * 10, [20.0] * 10)
        f = store.add_intent(tank="T1", date="2026-05-29", t=latest - ago, target_g=40, run_s=3, cycles_before=0,
                             source="demand")
        store.close_feed(f.id, "done", 41.5, latest - ago + 5)
        store.add_audit(t=latest - ago, user="ana", operator=None, command="ration", payload=None, origin="zenoh",
                        ok=True, result="ok")
    store.add_audit(t=latest, user="ana", operator=None, command="feed", payload=None, origin="zenoh", ok=True,
                    result="ok")
    store.close()
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    cfg = ["--config", str(tmp_path / "farm.toml")]
    for what in ("feeds", "surveys"):
        assert main(["history", "--tank", "T1", "--what", what, "--since", "1h", *cfg]) == 0
        assert len(capsys.readouterr().out.splitlines()) == 2, what            # the header and the newer
    assert main(["report", "--tank", "T1", "--since", "30m", "--json", *cfg]) == 0
    assert [s["t"] for s in json.loads(capsys.readouterr().out)["surveys"]] == [pytest.approx(latest - 600)]
    assert main(["audit", "--since", "1h", "--json", *cfg]) == 0
    assert [r["command"] for r in json.loads(capsys.readouterr().out)] == ["ration", "feed"]


def test_a_ledger_behind_the_wall_clock_is_measured_back_from_the_wall(farm_toml, capsys):
    """A real farm's ledger read months later: "1d" is the last day, not the ledger's last."""
    assert main(["history", "--tank", "T1", "--what", "feeds", "--since", "1d", "--config", farm_toml]) == 0
    assert capsys.readouterr().out.splitlines()[1:] == []


@pytest.mark.parametrize("to_file", [True, False])
def test_fishfarm_history_exports_every_row_past_the_queryable_s_limit(ledger, farm_toml, tmp_path, capsys,
                                                                        monkeypatch, to_file):
    """The command stopped at MAX_ROWS (a ledger of 150,081 fish gave 100,000, exit 0), and rows
    of one survey share its time: no narrower range splits them. The queryable's reply keeps it."""
    import controller.history
    ledger.add_survey("T1", T + 3 * DAY, "sparus_aurata", "big", [11.0] * 30, [float(w) for w in range(1, 31)])
    monkeypatch.setattr(controller.history, "MAX_ROWS", 10)
    out = tmp_path / "fish.csv"
    code = main(["history", "--tank", "T1", "--what", "fish", "--config", farm_toml,
                 *(["--csv", str(out)] if to_file else [])])
    captured = capsys.readouterr()
    text = out.read_text() if to_file else captured.out
    rows = list(csv.DictReader(io.StringIO(text)))
    assert code == 0 and len(rows) == 33
    assert [float(r["weight_g"]) for r in rows] == [20.0, 30.0, *range(1, 31), 40.0]
    assert captured.err == (f"33 rows: {out}\n" if to_file else "")
    reply = query_reply(ledger, load_config("config/farm.toml"), "history/fish/T1", {}, T)
    assert len(reply["rows"]) == 10 and reply["truncated"] is True


def test_the_export_streams_the_ledger_in_bounded_memory(ledger, farm_toml, tmp_path, capsys):
    """150,000 fish as one list of rows took ~100 MB; streamed, the export's peak does not grow with
    the rows (tracemalloc counts Python's allocations: the rows, not SQLite's page cache)."""
    import tracemalloc
    out = tmp_path / "fish.csv"

    def peak_mib(fish: int) -> float:
        ledger.add_survey("T3", T + fish, "sparus_aurata", "big", [11.0] * fish, [25.0] * fish)
        tracemalloc.start()
        try:
            assert main(["history", "--tank", "T3", "--what", "fish", "--config", farm_toml, "--csv", str(out),
                         "--since", iso(T + fish)]) == 0
            return tracemalloc.get_traced_memory()[1] / 2**20
        finally:
            tracemalloc.stop()
    small, large = peak_mib(2_000), peak_mib(40_000)
    assert f"40000 rows: {out}" in capsys.readouterr().err
    assert large < small + 2, (small, large)          # as a list: ~12 MB more


def test_a_text_cell_a_spreadsheet_would_run_as_a_formula_is_quoted(ledger, farm_toml, capsys):
    """An operator's name or reason beginning with = + - @ (tab, CR) was written as it was: a
    spreadsheet opening the CSV ran it (OWASP's CSV injection). Numbers are left as numbers."""
    for i, (who, reason) in enumerate([("=HYPERLINK(\"http://x\")", "+cmd|' /C calc'!A0"), ("-2+3", "@SUM(A1)"),
                                       ("\tana", "\rgrading"), ("ana", "a=b, -5 g"), ("'bob", "")]):
        ledger.add_stock_event(t=T + 3 * DAY + i, tank="T1", kind="mortality", count=2 + i,
                               to_tank=None, who=who, reason=reason)
    assert main(["history", "--tank", "T1", "--what", "stock", "--since", iso(T + 3 * DAY), "--config",
                 farm_toml]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert [(r["who"], r["reason"]) for r in rows] == [
        ("'=HYPERLINK(\"http://x\")", "'+cmd|' /C calc'!A0"), ("'-2+3", "'@SUM(A1)"), ("'\tana", "'\rgrading"),
        ("ana", "a=b, -5 g"), ("'bob", "")]
    assert [r["count"] for r in rows] == ["2", "3", "4", "5", "6"]
    from controller.cli.csvio import text_cell
    assert [text_cell(v) for v in (-3.5, -2, None, "-3.5")] == [-3.5, -2, None, "'-3.5"]


@pytest.mark.parametrize("what", ["surveys", "stock", "feeds"])
def test_a_row_s_printed_time_given_back_as_since_or_until_takes_the_row_in(tmp_path, what):
    """Rows at microsecond times (as the ledger keeps them), several within one second: each is
    written to the millisecond, in order, and its written time as --until, --since or both returns
    it (written to the second, --until of a row's own time left the row out)."""
    import random
    rng = random.Random(7)
    store = Store(tmp_path / "ledger.db")
    times = sorted(T + rng.choice([0, 1, 5]) + rng.randrange(1_000_000) / 1e6 for _ in range(30))
    for i, t in enumerate(times):
        if what == "surveys":
            store.add_survey("T1", t, "sparus_aurata", f"{i}.json", [10.0 + i], [20.0])
        elif what == "stock":
            store.add_stock_event(t=t, tank="T1", kind="mortality", count=1, to_tank=None, who="ana")
        else:
            f = store.add_intent(tank="T1", date="2026-05-28", t=t, target_g=40, run_s=3, cycles_before=i,
                                 source="demand")
            store.close_feed(f.id, "done", 40.0, t + 1)
    _, rows, _ = history(store, what, "T1")
    written = [r[0] for r in rows]
    assert len(written) == len(times) and written == sorted(written)
    assert len(set(written)) == len({round(t, 3) for t in times})      # apart to the millisecond
    for stamp in written:
        at = parse_time(stamp, "until", T, durations=False)
        for since, until in ((None, at), (at, None), (at, at)):
            _, got, _ = history(store, what, "T1", since, until)
            assert stamp in [r[0] for r in got], (stamp, since, until)
        _, got, _ = history(store, what, "T1", None, at)
        assert all(r[0] <= stamp for r in got)
    store.close()


def test_stock_rows_carry_the_ledger_s_event_id(ledger):
    """Two deaths entered alike at one millisecond were two rows no one could tell apart, or match
    to the ledger (the surveys and feeds rows carry theirs): the last column is the event's id."""
    first = ledger.add_stock_event(t=T + 3 * DAY, tank="T1", kind="mortality", count=2, to_tank=None, who="ana")
    second = ledger.add_stock_event(t=T + 3 * DAY, tank="T1", kind="mortality", count=2, to_tank=None, who="ana")
    cols, rows, _ = history(ledger, "stock", "T1")
    assert cols[-1] == "event" and cols[:7] == ("time", "kind", "count", "from_tank", "to_tank", "who", "reason")
    ids = [r[-1] for r in rows]
    assert ids == [e["id"] for e in ledger.stock_events()] and ids[-2:] == [first, second] and first != second


def test_a_tank_taken_out_of_the_config_keeps_its_history_readable(ledger, tmp_path, capsys):
    """T1 taken out of farm.toml (or renamed): its surveys, feeds and stock events stay in the ledger
    and `history` refused them ("no tank 'T1'"), so they could not be read without the old config.
    They are read as recorded, with a line saying so; an id the ledger never held is still refused."""
    import tomllib
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    raw["tanks"] = [t for t in raw["tanks"] if t["id"] != "T1"]
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    cfg = str(tmp_path / "farm.toml")
    assert main(["history", "--tank", "T1", "--what", "fish", "--config", cfg]) == 0
    out, err = capsys.readouterr()
    assert [float(r["weight_g"]) for r in csv.DictReader(io.StringIO(out))] == [20.0, 30.0, 40.0]
    assert f"tank T1 is not in {cfg}: its ledger rows as recorded" in err
    assert main(["history", "--tank", "T99", "--what", "fish", "--config", cfg]) == 2
    err = capsys.readouterr().err
    assert "--tank: no tank 'T99'" in err and "none of that id in the ledger either" in err and err.count("\n") == 1
