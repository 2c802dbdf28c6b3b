"""``fishfarm report``: a tank's figures between surveys, worked out here from their definitions
(SGR = 100·ln(W2/W1)/days; gain = N2·W2 − N1·W1 + fish out weighed when they left; FCR = feed /
gain, net FCR = feed / (gain − the dead fish's weight); K = 100·W/L³; days to target =
100·ln(target/W)/SGR) on a ledger written through the store."""
from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
import tomli_w

from controller.cli import main
from controller.store import Store

DAY = 86_400.0
T1 = 1_780_000_000.0


@pytest.fixture
def farm(tmp_path):
    import tomllib
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    stock = next(t["stock"] for t in raw["tanks"] if t["id"] == "T1")
    store = Store(tmp_path / "ledger.db")
    store.add_survey("T1", T1, "sparus_aurata", "a", [12.0] * 50, [20.0] * 50)
    store.add_survey("T1", T1 + 10 * DAY, "sparus_aurata", "b", [13.5] * 40, [30.0] * 40)
    store.add_survey("T2", T1, "sparus_aurata", "other tank", [5.0] * 10, [999.0] * 10)
    store.add_stock_event(t=T1 + 5 * DAY, tank="T1", kind="mortality", count=100, to_tank=None, who="op", reason="")
    for i, (t, phase) in enumerate([(T1 - 3600, "done"), (T1 + DAY, "done"), (T1 + 2 * DAY, "done"),
                                    (T1 + 9 * DAY, "done"), (T1 + 4 * DAY, "aborted"), (T1 + 11 * DAY, "done")]):
        f = store.add_intent(tank="T1", date=f"d{i}", t=t, target_g=1000, run_s=80, cycles_before=i, source="demand")
        store.close_feed(f.id, phase, 1000.0 if phase == "done" else None, t + 90)
    store.close()
    return tmp_path, stock


def run(capsys, *args):
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_the_figures_between_two_surveys_follow_their_definitions(farm, capsys):
    path, stock = farm
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(path / "farm.toml"), "--json",
                       "--target", "400")
    assert code == 0
    r = json.loads(out)
    [i] = r["intervals"]
    sgr = 100 * math.log(30 / 20) / 10
    w_mid = 20 * (30 / 20) ** 0.5                                  # the dead fish's weight at day 5
    gain = (stock - 100) * 30 - stock * 20 + 100 * w_mid
    assert i["sgr_pct"] == pytest.approx(sgr) and i["days"] == pytest.approx(10)
    assert i["feed_g"] == 3000                                     # the three done feeds between
    assert i["gain_g"] == pytest.approx(gain) and i["fcr"] == pytest.approx(3000 / gain)
    # the net FCR: the growth the farm kept, the dead fish's weight left out of the gain
    assert i["died_g"] == pytest.approx(100 * w_mid) and i["fcr_net"] == pytest.approx(3000 / (gain - 100 * w_mid))
    s1, s2 = r["surveys"]
    assert (s1["stock"], s2["stock"]) == (stock, stock - 100)
    assert s1["k"] == pytest.approx(100 * 20 / 12**3) and s2["k"] == pytest.approx(100 * 30 / 13.5**3)
    assert r["grading"] is False and s2["cv_pct"] == 0
    days = 100 * math.log(400 / 30) / sgr
    assert r["projection"]["days"] == pytest.approx(days)
    assert [d[2] for d in r["feed_per_day"]] == [1000.0] * 5
    # fitted to both surveys: the same growth; its 95 % interval from each survey's standard error
    # (CV 0 counts as 5 %: a sampled CV is not trusted below), 1.96 · √(se1² + se2²) / days
    fit = r["fit"]
    assert fit["sgr_pct_day"] == pytest.approx(sgr) and fit["fcr"] == pytest.approx(3000 / gain)
    assert fit["fcr_net"] == pytest.approx(3000 / (gain - 100 * w_mid))
    assert fit["sgr_ci_pct_day"] == pytest.approx(100 * 1.96 * math.hypot(0.05 / 50**0.5, 0.05 / 40**0.5) / 10,
                                                  rel=1e-3)
    assert fit["fcr_ci"][0] < fit["fcr"] < fit["fcr_ci"][1] and r["projection"]["basis"] == "fit"
    # the fitted weight across the window: two surveys, two parameters, so through both means
    t, w, ci = zip(*fit["curve"], strict=True)
    assert (t[0], t[-1]) == (T1, T1 + 10 * DAY) and list(t) == sorted(t)
    assert (w[0], w[-1]) == (pytest.approx(20), pytest.approx(30)) and all(c > 0 for c in ci)
    # the projection grows from the fitted weight at the newest survey to the target on its day
    p = r["projection"]
    assert p["weight_g"] == pytest.approx(w[-1])
    assert p["weight_g"] * math.exp(p["sgr_pct"] / 100 * p["days"]) == pytest.approx(400)


def test_the_page_draws_the_fitted_growth_and_its_band():
    from controller.plotting import pyplot
    from controller.report_plot import _draw_fit
    fig, ax = pyplot().subplots()
    curve = [[T1 + d * DAY, 20.0 * 1.02**d, 5.0] for d in range(11)]
    _draw_fit(ax, {"curve": curve, "model": "sgr", "surveys": 3})
    [line] = ax.lines                                            # at its dates: days since 1970
    assert list(line.get_xdata()) == pytest.approx([T1 / DAY + d for d in range(11)])
    assert list(line.get_ydata()) == pytest.approx([c[1] for c in curve])
    [band] = ax.collections                                      # 95 %: w / 1.05 .. w · 1.05
    ys = band.get_paths()[0].vertices[:, 1]
    assert ys.min() == pytest.approx(20 / 1.05) and ys.max() == pytest.approx(20 * 1.02**10 * 1.05)
    _draw_fit(ax, None)                                          # no fit: nothing more drawn
    assert len(ax.lines) == 1


def test_the_text_report_and_its_page(farm, capsys):
    path, stock = farm
    png = path / "report.png"
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(path / "farm.toml"), "--png", str(png))
    assert code == 0 and png.stat().st_size > 10_000
    died = 100 * 20 * (30 / 20) ** 0.5
    gain = (stock - 100) * 30 - stock * 20 + died
    assert f"FCR {3000 / gain:.2f}, net {3000 / (gain - died):.2f} ({died:.0f} g died)" in out
    assert "SGR 4.05 %/day" in out and "uniformity: CV 0.0 % (within 30 %)" in out
    assert "fitted to 2 surveys since 2026-05-28 (10.0 d, 90 fish): SGR 4.05 ± " in out
    assert f"written: {png}" in out


def test_a_spread_stock_is_flagged_for_grading(farm, capsys):
    path, _ = farm
    store = Store(path / "ledger.db")
    store.add_survey("T1", T1 + 20 * DAY, "sparus_aurata", "c", [14.0] * 12, [20.0, 30.0, 40.0, 70.0] * 3)
    store.close()
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(path / "farm.toml"))
    assert code == 0 and "GRADE: above 30 %" in out


@pytest.mark.parametrize(("args", "fault"), [
    (["--tank", "T99"], "--tank: no tank 'T99'"),
    (["--tank", "T1", "--since", "yesterdayish"], "--since"),
    (["--tank", "T1", "--since", "1999-01-01"], "--since: '1999-01-01': 1999-01-01T00:00:00Z is before 2000"),
    (["--tank", "T1", "--since", "99999d"], "--since: '99999d' reaches back before 2000"),
    (["--tank", "T1", "--target", "-5"], "--target: must be a finite weight above 0 g, not -5"),
    (["--tank", "T1", "--target", "0"], "--target: must be a finite weight above 0 g, not 0"),
    (["--tank", "T1", "--target", "inf"], "--target: must be a finite weight above 0 g, not inf"),
    (["--tank", "T1", "--target", "nan"], "--target: must be a finite weight above 0 g, not nan"),
])
def test_bad_input_is_one_line_and_exit_2(farm, capsys, args, fault):
    path, _ = farm
    code, out, err = run(capsys, "report", "--config", str(path / "farm.toml"), *args)
    assert code == 2 and fault in err and err.count("\n") == 1 and out == ""


def test_a_tank_never_surveyed_says_so(farm, capsys):
    path, _ = farm
    code, out, _ = run(capsys, "report", "--tank", "T3", "--config", str(path / "farm.toml"), "--png",
                       str(path / "empty.png"))
    assert code == 0 and "no survey in the ledger for this tank" in out and (path / "empty.png").exists()


def test_a_range_with_no_survey_says_how_many_came_before(farm, capsys):
    """It said 'no survey in the ledger for this tank' of a tank surveyed before --since."""
    path, _ = farm
    code, out, _ = run(capsys, "report", "--tank", "T1", "--since", "2099-01-01", "--config", str(path / "farm.toml"))
    assert code == 0 and "no survey of this tank since 2099-01-01 (2 before)" in out


def test_no_ledger_is_an_error_naming_it(tmp_path, capsys):
    import tomllib
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "none.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    code, _, err = run(capsys, "report", "--tank", "T1", "--config", str(tmp_path / "farm.toml"))
    assert code == 2 and "none.db: no ledger there" in err


def test_surveys_that_counted_no_fish_are_reported_not_taken_for_none(farm, capsys):
    path, _ = farm
    store = Store(path / "ledger.db")
    store.add_survey("T1", T1 + 12 * DAY, "sparus_aurata", "blocked", [], [])
    store.add_survey("T1", T1 + 19 * DAY, "sparus_aurata", "blocked again", [], [])
    store.add_survey("T3", T1, "sparus_aurata", "dark", [], [])
    store.close()
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(path / "farm.toml"))
    assert code == 0 and out.startswith("T1 (sparus_aurata): 2 surveys that counted fish, 2 that counted none\n")
    newest = time.strftime("%Y-%m-%d", time.gmtime(T1 + 19 * DAY))
    assert f"no fish counted: newest {newest}, 2 since the last survey that counted fish" in out
    assert "fitted to 2 surveys" in out                      # the figures rest on the two that counted
    code, out, _ = run(capsys, "report", "--tank", "T3", "--config", str(path / "farm.toml"), "--json")
    data = json.loads(out)
    assert data["surveys"] == [] and [e["source"] for e in data["empty_surveys"]] == ["dark"]
    code, out, _ = run(capsys, "report", "--tank", "T3", "--config", str(path / "farm.toml"))
    assert "0 surveys that counted fish, 1 that counted none" in out and "no survey in the ledger" not in out


@pytest.mark.parametrize("few", [1, 9])
def test_surveys_that_counted_too_few_fish_to_weigh_the_tank_are_reported_apart(farm, capsys, few):
    """``[surveys] min_weighed_fish`` 10 (farm.toml): a survey of fewer is listed, not figured on."""
    path, _ = farm
    store = Store(path / "ledger.db")
    store.add_survey("T1", T1 + 12 * DAY, "sparus_aurata", "blocked", [], [])
    store.add_survey("T1", T1 + 19 * DAY, "sparus_aurata", "reef", [14.0] * few, [45.0] * few)
    store.close()
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(path / "farm.toml"))
    assert code == 0 and out.startswith("T1 (sparus_aurata): 2 surveys that counted fish, "
                                        "2 that counted too few fish to weigh the tank (1 none)\n"), out
    newest = time.strftime("%Y-%m-%d", time.gmtime(T1 + 19 * DAY))
    assert f"too few fish to weigh the tank ({few}): newest {newest}, 2 since the last survey" in out
    assert "fitted to 2 surveys" in out and "45.0 g" not in out
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(path / "farm.toml"), "--json")
    data = json.loads(out)
    assert [s["fish"] for s in data["surveys"]] == [50, 40]
    assert [(e["source"], e["fish"]) for e in data["empty_surveys"]] == [("blocked", 0), ("reef", few)]


@pytest.mark.parametrize("command", ["report", "history", "cleaner map"])
@pytest.mark.parametrize("content", ["empty", "other sqlite", "text", "older schema"])
def test_a_file_that_is_not_a_ledger_is_refused_and_left_as_it_was(tmp_path, capsys, command, content):
    """report, history and the cleaner's map read the ledger only: pointed at another file they exit
    2 naming it and write nothing into it (they used to add the ledger's 12 tables to any SQLite or
    empty file; the map migrated an older ledger in place, which report then read as current)."""
    import sqlite3
    import tomllib
    path = tmp_path / "x.db"
    if content == "text":
        path.write_text("not a database\n")
    elif content != "empty":
        db = sqlite3.connect(path)
        db.execute("CREATE TABLE foo (a)")
        if content == "older schema":
            db.execute("PRAGMA user_version = 2")
        db.commit()
        db.close()
    else:
        path.write_bytes(b"")
    before = path.read_bytes()
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(path)}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    if command == "cleaner map":
        args = ["cleaner", "map", "--png", str(tmp_path / "map.png"), "--config", str(tmp_path / "farm.toml")]
    else:
        args = [command, "--tank", "T1", "--config", str(tmp_path / "farm.toml"),
                *(["--what", "surveys"] if command == "history" else [])]
    code, _, err = run(capsys, *args)
    assert code == 2 and err.count("\n") == 1 and "x.db" in err, err
    assert {"empty": "not a fishfarm ledger", "other sqlite": "not a fishfarm ledger", "text": "cannot read",
            "older schema": "start the controller once"}[content] in err
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["farm.toml", "x.db"]     # no -wal, -shm either


def test_a_target_with_one_survey_says_why_there_is_no_projection(farm, capsys):
    """--target 100 with one survey printed nothing of a projection, and '1 surveys'."""
    path, _ = farm
    code, out, _ = run(capsys, "report", "--tank", "T2", "--target", "100", "--config", str(path / "farm.toml"))
    assert code == 0 and out.startswith("T2 (sparus_aurata): 1 survey\n")
    assert "  no projection to 100 g: growth needs two surveys, this tank has 1 survey" in out


def test_no_target_and_a_target_reached_are_said_in_the_text_as_on_the_page(farm, capsys):
    """README: the text report names a missing projection's cause too. No target (none given, none
    in the tank's config) printed no line; a target below the fish's weight printed 'in 0 days' and
    today's date as when it is reached."""
    path, _ = farm
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(path / "farm.toml"))
    assert code == 0 and "  no projection: no target weight (--target, or the tank's target_weight_g)\n" in out
    for target in (25, 10):                       # the fitted weight today is ~30 g
        code, out, _ = run(capsys, "report", "--tank", "T1", "--target", str(target),
                           "--config", str(path / "farm.toml"))
        assert code == 0 and f"  no projection: at the target already (30 g, target {target} g)\n" in out, out
        assert "projection: " not in out.replace("no projection: ", "")
        code, out, _ = run(capsys, "report", "--tank", "T1", "--target", str(target), "--json",
                           "--config", str(path / "farm.toml"))
        assert json.loads(out)["projection"]["reached"] is True
    code, out, _ = run(capsys, "report", "--tank", "T1", "--target", "400", "--config", str(path / "farm.toml"))
    assert "  projection: 400 g at " in out and "at the target already" not in out


@pytest.mark.parametrize("offset_h", [5.5, -3.5, 0.0])
def test_the_report_dates_surveys_by_the_farm_s_day_as_rations_and_feeds_are(tmp_path, capsys, offset_h):
    """A survey at 18:47 UTC on a +5:30 farm is 00:17 of the next local day: the ration planned from
    it is that day's, and the report printed the UTC day."""
    import datetime as dt
    import tomllib
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    raw["utc_offset_h"] = offset_h
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    t1 = dt.datetime(2026, 12, 10, 18, 47, tzinfo=dt.UTC).timestamp()
    t2 = dt.datetime(2026, 12, 17, 2, 10, tzinfo=dt.UTC).timestamp()
    store = Store(tmp_path / "ledger.db")
    store.add_survey("T1", t1, "sparus_aurata", "a", [12.0] * 20, [20.0] * 20)
    store.add_survey("T1", t2, "sparus_aurata", "b", [13.0] * 20, [26.0] * 20)
    store.close()
    local = [(dt.datetime.fromtimestamp(t, dt.UTC) + dt.timedelta(hours=offset_h)).strftime("%Y-%m-%d")
             for t in (t1, t2)]
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(tmp_path / "farm.toml"), "--json")
    data = json.loads(out)
    assert code == 0 and [s["date"] for s in data["surveys"]] == local
    assert (data["intervals"][0]["date1"], data["intervals"][0]["date2"]) == tuple(local)
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(tmp_path / "farm.toml"))
    assert f"  survey {local[0]}: 20 fish" in out and f"  {local[0]} -> {local[1]} (" in out


@pytest.mark.parametrize("command", ["report", "history"])
def test_a_misspelt_tank_species_is_refused_as_run_refuses_it(farm, capsys, command):
    """Both read the tank's species (its rows, its name in the report): a config `run` would refuse
    was read as it stood, the misspelt name printed as the tank's fish."""
    import tomllib
    path, _ = farm
    raw = tomllib.loads((path / "farm.toml").read_text())
    raw["tanks"][1]["species"] = "sparus_aurta"
    (path / "bad.toml").write_text(tomli_w.dumps(raw))
    code, out, err = run(capsys, command, "--tank", "T1", "--config", str(path / "bad.toml"),
                         *(["--what", "surveys"] if command == "history" else []))
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "bad.toml: tanks.1.species: unknown species 'sparus_aurta'" in err and "sparus_aurata" in err


@pytest.mark.parametrize(("offset_h", "name"), [(5.5, "UTC+5:30"), (-3.5, "UTC-3:30"), (10.0, "UTC+10"), (0.0, "UTC")])
def test_the_page_s_dates_are_the_farm_s_local_days_as_the_text_s(tmp_path, capsys, offset_h, name):
    """The page's axis was in UTC while the text gave local days: a +10 farm's survey at 20:00 UTC
    stood on the day before the one the report named. Day ticks fall on local midnight, and each
    farm day's feed bar on its local noon."""
    import datetime as dt
    import tomllib

    import matplotlib.dates as mdates

    from controller.report_plot import page
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    raw["utc_offset_h"] = offset_h
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    t0 = dt.datetime(2026, 12, 10, 20, 0, tzinfo=dt.UTC).timestamp()
    store = Store(tmp_path / "ledger.db")
    store.add_survey("T1", t0, "sparus_aurata", "a", [12.0] * 20, [20.0] * 20)
    store.add_survey("T1", t0 + 9 * DAY, "sparus_aurata", "b", [13.0] * 20, [26.0] * 20)
    for d in range(1, 9):
        f = store.add_intent(tank="T1", date=f"2026-12-{10 + d}", t=t0 + d * DAY, target_g=500, run_s=40,
                             cycles_before=d, source="demand")
        store.close_feed(f.id, "done", 500.0, t0 + d * DAY + 60)
    store.close()
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(tmp_path / "farm.toml"), "--json")
    data = json.loads(out)
    assert code == 0 and data["utc_offset_h"] == offset_h
    fig = page(data, target_g=None)
    zone = dt.timezone(dt.timedelta(hours=offset_h))
    feed_ax = fig.axes[1]
    assert feed_ax.get_xlabel() == f"farm date ({name})"
    ticks = [mdates.num2date(x, tz=zone) for x in feed_ax.get_xticks()]
    assert len(ticks) >= 2 and all((t.hour, t.minute) == (0, 0) for t in ticks), ticks
    bars = [mdates.num2date(p.get_x() + p.get_width() / 2, tz=zone) for p in feed_ax.patches]
    assert [b.strftime("%Y-%m-%d") for b in bars] == [d for d, _, _ in data["feed_per_day"]]
    assert all((b.hour, b.minute) == (12, 0) for b in bars)


@pytest.mark.parametrize("source", ["surveyed around", "surveyed before only", "emptied", "never surveyed"])
def test_fish_moved_in_are_weighed_as_their_source_tank_had_them(tmp_path, capsys, source):
    """100 fish of ~200 g moved among 2,400 of 20-30 g were weighed at this tank's ~24 g: 17.6 kg
    they brought counted as grown here, an FCR of a fifth of the truth. They are weighed as the
    source's surveys had them: grown between the one before and the one after the transfer, or the
    one before as it stands when the source was emptied (its next survey is of other fish) or not
    surveyed again; a source never surveyed leaves them at this tank's weight."""
    import tomllib
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    stock = {t["id"]: t["stock"] for t in raw["tanks"]}
    store = Store(tmp_path / "ledger.db")
    store.add_survey("T1", T1, "sparus_aurata", "a", [12.0] * 50, [20.0] * 50)
    store.add_survey("T1", T1 + 10 * DAY, "sparus_aurata", "b", [13.5] * 50, [30.0] * 50)
    if source != "never surveyed":
        store.add_survey("T2", T1 + 2 * DAY, "sparus_aurata", "c", [26.0] * 40, [200.0] * 40)
    if source in ("surveyed around", "emptied"):
        store.add_survey("T2", T1 + 12 * DAY, "sparus_aurata", "d", [27.0] * 40, [220.0] * 40)
    n = stock["T2"] if source == "emptied" else 100
    store.add_stock_event(t=T1 + 5 * DAY, tank="T2", kind="transfer", count=n, to_tank="T1", who="op", reason="")
    f = store.add_intent(tank="T1", date="d", t=T1 + DAY, target_g=3000, run_s=80, cycles_before=0, source="demand")
    store.close_feed(f.id, "done", 3000.0, T1 + DAY + 90)
    store.close()
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(tmp_path / "farm.toml"), "--json")
    [i] = json.loads(out)["intervals"]
    w_in = {"surveyed around": 200 * (220 / 200) ** (3 / 10), "surveyed before only": 200.0, "emptied": 200.0,
            "never surveyed": 20 * (30 / 20) ** 0.5}[source]
    gain = (stock["T1"] + n) * 30 - stock["T1"] * 20 - n * w_in
    assert code == 0 and i["gain_g"] == pytest.approx(gain)
    assert i["fcr"] == (pytest.approx(3000 / gain) if gain > 0 else None)


def test_no_feed_recorded_is_no_fcr_not_zero(tmp_path, capsys):
    """Fish that grew with no feed in the ledger (fed by hand) read "FCR 0.00 (0.00-0.00, 95 %)":
    a conversion the ledger cannot know. None, and said so; the SCADA and JSON carry null."""
    import tomllib
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    store = Store(tmp_path / "ledger.db")
    for d, w in ((0, 20.0), (7, 24.0), (14, 29.0)):
        store.add_survey("T1", T1 + d * DAY, "sparus_aurata", str(d), [12.0] * 40, [w] * 40)
    store.close()
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(tmp_path / "farm.toml"), "--json")
    data = json.loads(out)
    assert code == 0 and all(i["feed_g"] == 0 and i["fcr"] is None and i["fcr_net"] is None for i in data["intervals"])
    assert data["fit"]["fcr"] is None and data["fit"]["fcr_ci"] == [None, None] and data["fit"]["fcr_net"] is None
    code, out, _ = run(capsys, "report", "--tank", "T1", "--config", str(tmp_path / "farm.toml"))
    assert "FCR 0.00" not in out and out.count("FCR n/a (no feed recorded)") == 3, out


def test_a_page_of_many_surveys_draws_the_newest_as_histograms_and_every_mean(tmp_path):
    """A histogram for each of 1,000 surveys took 30 s to draw (4,000: six minutes and 1 GB): the
    newest HISTOGRAMS are drawn as histograms, every survey's mean on the line."""
    from matplotlib.patches import Rectangle

    from controller.report_plot import HISTOGRAMS, page
    rng = np.random.default_rng(0)
    surveys = [{"t": T1 + k * 3 * 3600.0, "date": "d", "fish": 50, "mean_weight_g": 20 + 0.01 * k, "cv_pct": 20.0,
                "k": 1.5, "stock": 1000, "weights_g": list(rng.normal(20 + 0.01 * k, 4, 50))} for k in range(300)]
    report = {"tank": "T1", "species": "sparus_aurata", "utc_offset_h": 0.0, "surveys": surveys, "intervals": [],
              "empty_surveys": [], "grading_cv_pct": 30, "feed_per_day": []}
    fig = page(report, target_g=None)
    ax = fig.axes[0]
    bars = [p for p in ax.patches if isinstance(p, Rectangle)]
    assert 0 < len(bars) <= HISTOGRAMS * 20
    lefts = {round(b.get_x(), 6) for b in bars}                   # one histogram stands at each survey drawn
    assert len(lefts) == HISTOGRAMS
    [means] = [line for line in ax.lines if len(line.get_xdata()) == len(surveys)]
    assert list(means.get_ydata()) == pytest.approx([s["mean_weight_g"] for s in surveys])


@pytest.mark.parametrize("command", [["report", "--tank", "T1"], ["history", "--tank", "T1", "--what", "surveys"]])
def test_a_ledger_locked_by_another_process_is_refused_after_one_wait(farm, capsys, monkeypatch, command):
    """One read waits for the lock, then one line: the command read the ledger twice, each waiting
    SQLite's while (10-13 s at its 5 s, for the same refusal)."""
    import sqlite3

    from controller import ledger_read, store
    monkeypatch.setattr(ledger_read, "READ_WAIT_S", 0.2)
    busy = []

    def counted(path):
        try:
            return ledger_read.connect_read_only(path)
        except sqlite3.OperationalError as exc:
            busy.append(str(exc))
            raise
    monkeypatch.setattr(store, "connect_read_only", counted)
    path, _ = farm
    lock = sqlite3.connect(str(path / "ledger.db"), isolation_level=None)
    try:
        lock.execute("PRAGMA locking_mode=EXCLUSIVE")
        lock.execute("BEGIN EXCLUSIVE")
        code, out, err = run(capsys, *command, "--config", str(path / "farm.toml"))
    finally:
        lock.close()
    assert code == 2 and out == "" and err.strip().splitlines() == [
        f"fishfarm: {path / 'ledger.db'}: cannot read the ledger: database is locked"]
    assert busy == ["database is locked"]
