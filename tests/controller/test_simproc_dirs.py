"""The simulator's files (endpoints.json, the stereo rig's CALIB.json) live in a ``fishfarm-sim-*``
directory of the controller's. A controller killed outright (SIGKILL, a second signal, its stop
watchdog) cannot remove it: the next controller's start does, for every such directory whose
owner is gone, and never one of a live controller."""
from __future__ import annotations

import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from controller import simproc
from tests.controller.shutdown_rig import ROOT

OWNER = ("import sys; from controller.simproc import SimProcess; s = SimProcess(None, None); "
         "(s.dir / 'endpoints.json').write_text('{}'); print(s.dir, flush=True); sys.stdin.read()")


@pytest.fixture
def tmp(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    return tmp_path


def owner(tmp):
    """A process that made its simulator directory, as a controller does, and lives on until told."""
    proc = subprocess.Popen([sys.executable, "-c", OWNER], cwd=ROOT, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env={"TMPDIR": str(tmp), "PATH": "/usr/bin:/bin"})
    line = proc.stdout.readline().strip()
    assert line, "the owner did not start"
    return proc, Path(line)


def test_a_killed_controllers_directory_is_removed_and_a_live_ones_kept(tmp):
    dead, dead_dir = owner(tmp)
    live, live_dir = owner(tmp)
    try:
        dead.send_signal(signal.SIGKILL)
        dead.wait(timeout=30)
        assert dead_dir.is_dir() and live_dir.is_dir()
        assert dead_dir.parent == tmp and dead_dir.name.startswith("fishfarm-sim-")
        unrelated = tmp / "fishfarm-simulated-notes"
        unrelated.mkdir()
        lockless = tmp / "fishfarm-sim-olderversion"         # no owner to ask: not ours to judge
        lockless.mkdir()
        removed = simproc.sweep_leftovers()
        assert removed == [dead_dir]
        assert not dead_dir.exists()
        assert live_dir.is_dir() and (live_dir / "endpoints.json").exists()
        assert unrelated.is_dir() and lockless.is_dir()
        assert simproc.sweep_leftovers() == []                  # the live one still held
    finally:
        live.stdin.close()
        live.wait(timeout=30)
        live.stdout.close()
        dead.stdout.close()
    # it ended without stopping its SimProcess (as after SIGHUP's default did): the next start cleans up
    assert simproc.sweep_leftovers() == [live_dir]


def test_a_controller_start_sweeps_and_its_stop_removes_its_own(tmp):
    dead, dead_dir = owner(tmp)
    dead.kill()
    dead.wait(timeout=30)
    dead.stdout.close()
    sim = simproc.SimProcess(None, None)
    try:
        assert not dead_dir.exists()
        assert sim.dir.is_dir()
    finally:
        sim.kill()
        sim.remove_dir()
    assert not sim.dir.exists()
