"""``fishfarm demand`` as external scripts run it: a subprocess, a CSV in, JSON out."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller.cli.demand_cmd import replay, to_json
from devices.sim import contact_streams as cs

FISHFARM = str(Path(sys.executable).parent / "fishfarm")
ROOT = Path(__file__).resolve().parents[2]


def run(*args):
    return subprocess.run([FISHFARM, "demand", *map(str, args)], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    """Two tanks over half a day, times in seconds since midnight."""
    rng = np.random.default_rng(2)
    parts = [cs.tank_day(rng, tank, (f"{tank}-a", f"{tank}-b"), 0.0, 0.5, rate_hz=(0.8, 2.0),
                         turbulence_hz=0.03, episodes_per_day=16) for tank in ("T1", "T2")]
    stream = cs.merge(*parts)
    path = tmp_path_factory.mktemp("demand") / "contacts.csv"
    stream.write_csv(path)
    return stream, path


def test_replay_writes_the_contract_json(log, tmp_path):
    stream, path = log
    out = tmp_path / "out.json"
    r = run("--events", path, "--json", out)
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert set(doc) == {"demands", "faults"} and doc["faults"] == []
    assert all(set(d) == {"tank", "t_s"} for d in doc["demands"])
    for ep in stream.episodes:                       # every episode served within 60 s
        assert any(d["tank"] == ep.tank and ep.start <= d["t_s"] <= ep.start + 60 for d in doc["demands"])
    assert doc == json.loads(json.dumps(to_json(replay(str(path))[0])))   # the same code in-process


def test_json_dash_is_the_standard_output(log, tmp_path):
    stream, path = log
    r = subprocess.run([FISHFARM, "demand", "--events", path, "--json", "-"], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == json.loads(json.dumps(to_json(replay(str(path))[0])))
    assert list(tmp_path.iterdir()) == []                       # no file named '-'


def test_config_takes_tanks_from_farm_toml_and_skips_strangers(log, tmp_path):
    stream, path = log
    extra = tmp_path / "with_stranger.csv"
    lines = path.read_text().splitlines()
    lines.insert(5, f"{lines[4].split(',')[0]},T9,T9-z")
    extra.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.json"
    r = run("--events", extra, "--json", out, "--config", "config/farm.toml")
    assert r.returncode == 0, r.stderr
    assert "skipped 1 contacts" in r.stderr and "T9/T9-z" in r.stderr
    doc = json.loads(out.read_text())
    assert {d["tank"] for d in doc["demands"]} == {"T1", "T2"}
    # T3..T8 are configured but silent while nothing else fires in them: never "dead"
    assert doc["faults"] == []


@pytest.mark.parametrize(("body", "needle"), [
    ("t,tank,sensor\n1,T1,a\n", "header: expected 't_s,tank,sensor'"),
    ("t_s,tank,sensor\n1,T1,a\nabc,T1,a\n", "line 3, column t_s: not a number: 'abc'"),
    ("t_s,tank,sensor\n1_000,T1,a\n", "line 2, column t_s: not a number: '1_000'"),    # Python's, not CSV's
    ("t_s,tank,sensor\n5,T1,a\n4.5,T1,a\n", "line 3, column t_s: 4.5 is earlier"),
    ("t_s,tank,sensor\n5,T1,a,x\n", "line 2: 4 fields, expected 3"),
    ("t_s,tank,sensor\n5,,a\n", "line 2, column tank: empty"),
    ("t_s,tank,sensor\nnan,T1,a\n", "line 2, column t_s: nan is not a finite number"),
    ("", "empty file"),
    ("t_s,tank,sensor\n1,T\x001,a\n", "line 2, column tank: unprintable character '\\x00' in 'T\\x001'"),
    ("t_s,tank,sensor\n1,T1,a\n2,T1,\x1b[2Ja\n", "line 3, column sensor: unprintable character '\\x1b'"),
])
def test_bad_csv_is_one_line_exit_2(tmp_path, body, needle):
    path = tmp_path / "bad.csv"
    path.write_text(body)
    r = run("--events", path, "--json", tmp_path / "o.json")
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and needle in r.stderr and str(path) in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "o.json").exists()


@pytest.mark.parametrize("bad_line", [1, 2, 3000])
def test_bytes_that_are_not_utf8_are_named_by_their_own_line(tmp_path, bad_line):
    """Decoded a buffer at a time, a fault deep in a long log was put at the buffer's line."""
    rows = [b"t_s,tank,sensor"] + [b"%d,T1,T1-a" % i for i in range(1, 4000)]
    rows[bad_line - 1] = rows[bad_line - 1].replace(b"T1", b"T\xe91", 1) if bad_line > 1 else b"t_s,t\xff,sensor"
    path = tmp_path / "latin1.csv"
    path.write_bytes(b"\n".join(rows) + b"\n")
    r = run("--events", path, "--json", tmp_path / "o.json")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert f"{path}: line {bad_line}: not UTF-8 text" in r.stderr
    ok = tmp_path / "utf8.csv"                   # the same name in UTF-8 is a name like any other
    ok.write_bytes(b"\n".join([b"t_s,tank,sensor", "1,T\u00e91,a".encode()]) + b"\n")
    assert run("--events", ok, "--json", tmp_path / "o.json").returncode == 0


def test_missing_file_and_bad_config(tmp_path, log):
    r = run("--events", tmp_path / "nope.csv", "--json", tmp_path / "o.json")
    assert r.returncode == 2 and "nope.csv: no such file" in r.stderr
    farm = tmp_path / "farm.toml"
    farm.write_text((ROOT / "config/farm.toml").read_text() + "\n[demand]\nrepeat_seconds = 5\n")
    r = run("--events", log[1], "--json", tmp_path / "o.json", "--config", farm)
    assert r.returncode == 2 and r.stderr.strip() == f"fishfarm: {farm}: demand.repeat_seconds: unknown key"


def test_header_only_gives_empty_lists(tmp_path):
    path = tmp_path / "empty.csv"
    path.write_text("t_s,tank,sensor\n")
    out = tmp_path / "o.json"
    assert run("--events", path, "--json", out).returncode == 0
    assert json.loads(out.read_text()) == {"demands": [], "faults": []}


def test_a_log_given_twice_over_counts_each_contact_once_and_says_so(log, tmp_path):
    """Every row written twice raised 0.67 -> 21.8 false demands a tank-day (an outside tester)."""
    _, path = log
    lines = path.read_text().splitlines()
    doubled = tmp_path / "doubled.csv"
    doubled.write_text("\n".join([lines[0], *(row for line in lines[1:] for row in (line, line))]) + "\n")
    once, twice = tmp_path / "once.json", tmp_path / "twice.json"
    assert run("--events", path, "--json", once).returncode == 0
    r = run("--events", doubled, "--json", twice)
    assert r.returncode == 0, r.stderr
    assert json.loads(twice.read_text()) == json.loads(once.read_text())
    assert "rows repeated a contact of the same sensor at the same instant: each counted once" in r.stderr
