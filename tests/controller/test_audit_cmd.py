"""``fishfarm audit``: the audit rows the overrides wrote, read back from the ledger file."""
from __future__ import annotations

import asyncio
import json
import sqlite3
import time

import pytest
import tomli_w

from controller.cli import main
from controller.cli.audit_cmd import parse_since
from controller.errors import BadInput
from controller.overrides import Overrides
from controller.store import MIGRATIONS, Store
from devices.clock import ManualClock
from tests.controller.override_rig import Farm

CONTROL = "reason: control characters (newline, carriage return, escape...) are not allowed"


@pytest.fixture
def now():
    """The wall clock when the rows are written: ``--since 90s`` is taken from the command's own now."""
    return time.time()


@pytest.fixture
def ledger(tmp_path, now):
    """Three overrides: an hour ago, ten minutes ago and now; one refused; one authenticated."""
    path = tmp_path / "ledger.db"
    store = Store(path)
    farm = Farm(store)

    async def run():
        overrides = Overrides(farm)
        for ago, command, payload, user in [
                (3600, "ration", {"tank": "T1", "grams": 500, "operator": "ana"}, None),
                (600, "feed", {"tank": "T9", "grams": 20, "operator": "ana", "reason": "tab\there"}, "bob"),
                (0, "estop", {"operator": "eve", "reason": "[bold]x[/bold]"}, None)]:
            farm.clock = ManualClock(now - ago)
            await overrides.apply(command, payload, user=user)
            await asyncio.sleep(0)
    asyncio.run(run())
    store.close()
    return path


def run(capsys, *args):
    code = main(["audit", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def test_json_lists_every_row_with_who_did_it(ledger, capsys):
    code, out, err = run(capsys, "--db", ledger, "--json")
    assert code == 0 and err == ""
    rows = json.loads(out)
    assert [(r["who"], r["command"], r["ok"], r["result"]) for r in rows] == [
        ("ana (claimed)", "ration", True, "ok"), ("bob", "feed", False, CONTROL),
        ("eve (claimed)", "estop", True, "ok")]
    assert rows[1]["user"] == "bob" and rows[1]["operator"] == "ana" and rows[1]["origin"] == "zenoh"
    assert json.loads(rows[0]["payload"]) == {"tank": "T1", "grams": 500, "operator": "ana"}


@pytest.mark.parametrize("since, commands", [
    ("2h", ["ration", "feed", "estop"]), ("30m", ["feed", "estop"]), ("90s", ["estop"]),
    ("1d", ["ration", "feed", "estop"]), ("0.5h", ["feed", "estop"]),
])
def test_since_a_duration(ledger, capsys, since, commands):
    code, out, _ = run(capsys, "--db", ledger, "--json", "--since", since)
    assert code == 0 and [r["command"] for r in json.loads(out)] == commands


def test_since_an_iso_time_and_by_operator(ledger, capsys, now):
    import datetime as dt
    when = dt.datetime.fromtimestamp(now - 1800, dt.UTC)
    for text in (when.isoformat(), when.strftime("%Y-%m-%dT%H:%M:%S"), when.strftime("%Y-%m-%dT%H:%M:%SZ")):
        code, out, _ = run(capsys, "--db", ledger, "--json", "--since", text)
        assert code == 0 and [r["command"] for r in json.loads(out)] == ["feed", "estop"], text
    for name, commands in (("ana", ["ration", "feed"]), ("bob", ["feed"]), ("eve", ["estop"]), ("zed", [])):
        code, out, _ = run(capsys, "--db", ledger, "--json", "--operator", name)
        assert code == 0 and [r["command"] for r in json.loads(out)] == commands


def test_not_a_terminal_one_tab_separated_line_per_row(ledger, capsys):
    code, out, _ = run(capsys, "--db", ledger)
    lines = out.splitlines()
    assert code == 0 and lines[0] == "time\twho\tcommand\torigin\tresult\tpayload" and len(lines) == 4
    assert all(len(line.split("\t")) == 6 for line in lines)
    assert "tab\\there" in lines[2]                            # escaped, not a column break


def test_the_config_names_the_ledger(ledger, capsys, tmp_path):
    import tomllib
    raw = tomllib.loads(open("config/farm.toml").read())
    raw["store"] = {"path": str(ledger)}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    code, out, _ = run(capsys, "--config", tmp_path / "farm.toml", "--json")
    assert code == 0 and len(json.loads(out)) == 3
    # both: one was used and the other dropped without a word (an outside tester)
    code, out, err = run(capsys, "--config", tmp_path / "farm.toml", "--db", ledger, "--json")
    assert code == 2 and out == "" and err.count("\n") == 1 and "--db" in err and "--config" in err, err


@pytest.mark.parametrize("args, message", [
    (["--since", "yesterday"], "fishfarm: --since: 'yesterday' is neither an ISO time"),
    (["--since", "5 parsecs"], "fishfarm: --since: '5 parsecs' is neither an ISO time"),
    (["--since", "-5m"], "fishfarm: --since: '-5m' is neither an ISO time"),
    (["--operator", ""], "fishfarm: --operator: '' is no operator's name"),
    (["--operator", "  "], "fishfarm: --operator: '  ' is no operator's name"),
])
def test_bad_since_is_one_line_and_exit_2(ledger, capsys, args, message):
    code, out, err = run(capsys, "--db", ledger, *args)
    assert code == 2 and out == "" and err.startswith(message) and err.count("\n") == 1


def test_no_ledger_or_an_old_one_is_one_line_and_exit_2(tmp_path, capsys):
    code, _, err = run(capsys, "--db", tmp_path / "none.db")
    assert code == 2 and "none.db: no such ledger" in err and err.count("\n") == 1
    assert not (tmp_path / "none.db").exists()                 # looked at, never created
    old = tmp_path / "old.db"
    db = sqlite3.connect(old)
    db.executescript(";".join(MIGRATIONS[:3]) + "; PRAGMA user_version = 3;")
    db.close()
    code, _, err = run(capsys, "--db", old)
    assert code == 2 and "no audit in this ledger" in err and err.count("\n") == 1
    (tmp_path / "junk.db").write_bytes(b"not sqlite at all" * 100)
    code, _, err = run(capsys, "--db", tmp_path / "junk.db")
    assert code == 2 and "junk.db" in err and err.count("\n") == 1


def test_parse_since():
    assert parse_since("10m", 1000.0) == 400.0 and parse_since("1w", 604800.0) == 0.0
    assert parse_since("1970-01-01T00:01:00+01:00", 0.0) == -3540.0
    with pytest.raises(BadInput):
        parse_since("", 0.0)


def test_a_duration_no_float_holds_is_refused():
    with pytest.raises(BadInput, match="--since"):
        parse_since("1" * 400 + "d", 1_780_000_000.0)
