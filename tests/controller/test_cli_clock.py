"""``fishfarm clock``: the file it makes is the clock the farm's processes share, and it shows one."""
from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import threading
import tty
from pathlib import Path

import pytest

from controller.cli import main as fishfarm_main
from devices.clock_file import LEASE_S
from devices.elastic_clock import ElasticClock

ROOT = Path(__file__).resolve().parents[2]


def test_made_clock_runs_slow_until_the_awaited_speak_then_fast(tmp_path, capsys):
    path = tmp_path / "clock"
    assert fishfarm_main(["clock", "--out", str(path), "--slow", "360", "--fast", "8640",
                          "--farm-start", "2026-05-29T16:00:00Z", "--await", "sim", "--await", "controller"]) == 0
    sim, ctl = ElasticClock(path), ElasticClock(path)
    try:
        assert abs(sim.now() - 1_780_070_400.0) < 360 * 60        # started at the farm time given
        assert (sim.slow, sim.fast, sim.speed) == (360.0, 8640.0, 360.0)
        sim.claim("sim")
        sim.idle_until(sim.now() + 3600, "no fish asking")
        assert sim.speed == 360.0                                  # the controller has not spoken
        ctl.claim("controller")
        ctl.idle_until(ctl.now() + 7200, "next survey")
        assert ctl.speed == 8640.0                                 # both idle: fast
        capsys.readouterr()
        assert fishfarm_main(["clock", "--show", str(path)]) == 0
        shown = json.loads(capsys.readouterr().out)
        assert shown["speed"] == 8640.0 and shown["fast_until"] is not None
        assert [(s["name"], s["state"], s["why"]) for s in shown["slots"]] == [
            ("sim", "idle", "no fish asking"), ("controller", "idle", "next survey")]
        ctl.busy(why="moving")
        assert sim.speed == 360.0
    finally:
        sim.close()
        ctl.close()


@pytest.mark.parametrize("args, names", [
    (["--slow", "0", "--fast", "10"], "--slow"),
    (["--slow", "100", "--fast", "10"], "--slow"),
    (["--slow", "10"], "--fast"),
    (["--slow", "1", "--fast", "nan"], "--fast"),
    (["--slow", "1", "--fast", "10", "--farm-start", "yesterday"], "--farm-start"),
    (["--slow", "1", "--fast", "10", "--await", "a-name-longer-than-16"], "--await"),
    (["--slow", "1e300", "--fast", "1e300"], "--slow"),       # taken before; --show overflowed
    (["--slow", "1", "--fast", "1e300"], "--fast"),
    (["--slow", "1", "--fast", "10", "--farm-start", "9999-12-31T23:59:59"], "--farm-start"),
    (["--slow", "1", "--fast", "10", "--farm-start", "253402300800"], "--farm-start"),
    (["--slow", "1", "--fast", "10", "--farm-start", "0"], "--farm-start"),
    (["--slow", "1", "--fast", "10", "--farm-start", "1970-01-01"], "--farm-start"),
    (["--slow", "1", "--fast", "10", "--farm-start", "2200-01-01"], "--farm-start"),
    (["--slow", "1", "--fast", "10", "--await", "simulator"], "--await"),   # nobody claims it: slow for good
    (["--slow", "1", "--fast", "10", "--await", "sim", "--await", "sim"], "--await"),
])
def test_bad_clocks_are_refused_in_one_line(tmp_path, capsys, args, names):
    assert fishfarm_main(["clock", "--out", str(tmp_path / "c"), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and names in err[0]
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("command", ["run", "sim"])
@pytest.mark.parametrize("flag, value", [("--epoch-farm", "1e300"), ("--epoch-wall", "1e300"),
                                         ("--epoch-farm", "-1e10"), ("--epoch-wall", "0"),
                                         ("--epoch-farm", "7258118400")])
def test_epochs_outside_the_farm_years_are_refused_in_one_line(tmp_path, capsys, command, flag, value):
    # the old code ran with farm time frozen (1e300), stuck at 1970, or in 1653
    extra = ["--endpoints", str(tmp_path / "e.json")] if command == "sim" else []
    assert fishfarm_main([command, "--config", str(tmp_path / "none.toml"), *extra, flag, value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag in err[0] and "2000-2199" in err[0]


@pytest.mark.parametrize("command", ["run", "sim"])
@pytest.mark.parametrize("args, said", [
    (["--speed", "60"], "fishfarm: --clock: the clock file sets farm time: not with --speed"),
    (["--speed", "1"], "fishfarm: --clock: the clock file sets farm time: not with --speed"),     # the default, given
    (["--speed", "1.0"], "fishfarm: --clock: the clock file sets farm time: not with --speed"),
    (["--epoch-farm", "1780000000"], "fishfarm: --clock: the clock file sets farm time: not with --epoch-farm"),
])
def test_run_and_sim_refuse_a_clock_file_with_speed_or_epochs_alike(tmp_path, capsys, command, args, said):
    # the simulator ignored them without a word while run refused them
    clock = tmp_path / "clock"
    assert fishfarm_main(["clock", "--out", str(clock), *MAKE]) == 0
    capsys.readouterr()
    extra = ["--endpoints", str(tmp_path / "e.json")] if command == "sim" else []
    assert fishfarm_main([command, "--config", str(tmp_path / "none.toml"), *extra, "--clock", str(clock), *args]) == 2
    assert capsys.readouterr().err.strip() == said


def test_sim_refuses_hear_without_a_clock(tmp_path, capsys):
    assert fishfarm_main(["sim", "--config", str(tmp_path / "none.toml"), "--endpoints", str(tmp_path / "e.json"),
                          "--hear", "tcp/127.0.0.1:7447"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("fishfarm: --hear: only with --clock")


def test_show_prints_the_segment_and_marks_dead_slots(tmp_path, capsys):
    path = tmp_path / "clock"
    assert fishfarm_main(["clock", "--out", str(path), *MAKE, "--await", "sim", "--await", "controller"]) == 0
    gone = subprocess.run([sys.executable, "-c", "import sys\nfrom devices.elastic_clock import ElasticClock\n"
                           "ElasticClock(sys.argv[1]).claim('sim')", str(path)], cwd=ROOT, timeout=60)
    assert gone.returncode == 0
    capsys.readouterr()
    assert fishfarm_main(["clock", "--show", str(path)]) == 0
    shown = json.loads(capsys.readouterr().out)
    # (drawn by the sim: slow until its word's lease lapsed; or drawn again by this reader, a second
    # on: slow, its holder dead -- either way the segment starts at the slow speed)
    assert shown["lease_s"] == LEASE_S and shown["segment"]["speed"] == 360.0
    assert shown["segment"]["farm0"].startswith("2026-05-29")
    assert [(s["name"], s["state"], s.get("dead", False)) for s in shown["slots"]] == [
        ("sim", "busy", True), ("controller", "awaited", False)]


def test_show_refuses_what_is_no_clock(tmp_path, capsys):
    (tmp_path / "x").write_bytes(b"not a clock" * 100)
    assert fishfarm_main(["clock", "--show", str(tmp_path / "x")]) == 2
    assert fishfarm_main(["clock", "--show", str(tmp_path / "missing")]) == 2
    assert fishfarm_main(["clock"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and str(tmp_path / "x") in err[0] and "missing" in err[1] and "--out" in err[2]
    assert err[1] == f"fishfarm: --show: {tmp_path / 'missing'}: no such file"
    for size in (0, 11, 847):           # shorter than a clock file: named, not mmap's own complaint
        (tmp_path / "short").write_bytes(b"x" * size)
        assert fishfarm_main(["clock", "--show", str(tmp_path / "short")]) == 2
        line = capsys.readouterr().err.strip()
        assert line == (f"fishfarm: --show: {tmp_path / 'short'}: not a fishfarm clock file ({size} bytes, "
                        "a clock file has 984)")


MAKE = ["--slow", "360", "--fast", "8640", "--farm-start", "2026-05-29T16:00:00Z"]


def test_out_follows_the_output_rules(tmp_path, capsys):
    os.mkdir(tmp_path / "d")
    (tmp_path / "farm.toml").write_text("site = 'demo'\n")
    for out, says in ((tmp_path / "d", "a directory, not a file"),
                      (tmp_path / "farm.toml", "exists and is not a clock file"),
                      (Path("/proc/version"), "")):
        assert fishfarm_main(["clock", "--out", str(out), *MAKE]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(out) in err[0] and says in err[0] and "internal error" not in err[0]
    assert (tmp_path / "farm.toml").read_text() == "site = 'demo'\n"   # the old code renamed a clock over it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d", "farm.toml"]   # no ..tmp left
    assert list((tmp_path / "d").iterdir()) == []


def test_out_writes_into_a_device_or_a_fifo_never_replaces_it(tmp_path):
    # a pty, not /dev/null: the old code, run as root, renamed a plain file over /dev/null
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        device = os.ttyname(slave)
        assert fishfarm_main(["clock", "--out", device, *MAKE]) == 0
        assert stat.S_ISCHR(os.stat(device).st_mode)
        assert os.read(master, 4096)[:4] == b"FFCK"
    finally:
        os.close(master)
        os.close(slave)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    assert fishfarm_main(["clock", "--out", str(fifo), *MAKE]) == 0
    reader.join(timeout=30)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert len(got[0]) == 984 and got[0][:4] == b"FFCK"


def test_out_replaces_a_clock_file_only_while_no_farm_runs_on_it(tmp_path, capsys):
    path = tmp_path / "clock"
    assert fishfarm_main(["clock", "--out", str(path), *MAKE]) == 0
    c = ElasticClock(path)
    c.claim("controller")                      # (this process: alive)
    capsys.readouterr()
    assert fishfarm_main(["clock", "--out", str(path), *MAKE]) == 2
    assert f"pid {os.getpid()}" in capsys.readouterr().err
    c.release()
    c.close()
    assert fishfarm_main(["clock", "--out", str(path), *MAKE]) == 0
