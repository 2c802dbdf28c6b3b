"""Stop means stop: the real ``fishfarm run`` process, signalled in each phase of its life, ends
within 5 s, leaves no simulator child behind (nor a zombie), closes its ledger cleanly and stops
the auger it was running; a second signal ends it at once."""
import asyncio
import json
import logging
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
import tomli_w

from controller import app, hearing, shutdown
from controller.alarms import Alarms
from controller.config import load_config
from controller.store import Store
from devices.clock import ScaledClock
from hil_tests.farm import without_cleaner  # the demo farm's feeder alone
from tests.controller.shutdown_rig import PHASES, ROOT, RunningController, free_port, proc_state

LIMIT_S = 5.0
# SIGHUP: a closed terminal or a dropped SSH session; stop means stop there too, not a crash
SIGNALS = {"SIGINT-to-group": signal.SIGINT, "SIGTERM": signal.SIGTERM, "SIGHUP": signal.SIGHUP}


@pytest.fixture
def controller(tmp_path, request):
    phase = request.param
    rc = RunningController(tmp_path, phase, speed=5.0)
    yield rc
    rc.kill()


@pytest.mark.parametrize("sig", SIGNALS.values(), ids=SIGNALS.keys())
@pytest.mark.parametrize("controller", PHASES, indirect=True)
def test_a_signal_stops_the_controller_within_5_s(controller, sig):
    controller.reach()
    sent = controller.send(sig)
    rc = controller.wait_exit(sent)
    log = controller.log()
    assert rc == 0, f"exit {rc}:\n{log[-3000:]}"
    assert controller.exit_s < LIMIT_S, f"{controller.phase}: {controller.exit_s:.2f} s to stop:\n{log[-3000:]}"
    assert "controller stopped in" in log                 # the orderly way, not the watchdog's
    assert controller.leftovers() == []                   # nothing started for this farm runs on
    if controller.sim_pid is not None:
        assert not controller.sim_alive(), f"simulator pid {controller.sim_pid} left behind"
        assert "simulated devices stopped" in log or controller.phase == "sim_died"
        assert not controller.sim_dir.exists(), f"{controller.sim_dir} left behind"
    if controller.phase != "starting" or controller.db.exists():     # starting: opened after the simulator
        assert controller.ledger_clean() is None, controller.ledger_clean()
    if controller.phase == "starting":
        assert "controller for site" not in log           # it really was stopped while starting
    if controller.phase == "feeding":
        assert_auger_stopped_short(controller)


def assert_auger_stopped_short(controller):
    """The run in progress ended before the simulator did, well short of its aim: stopped by the
    controller on its way out, not run to its end nor left turning when the simulator went."""
    truth = [json.loads(line) for line in controller.truth.read_text().splitlines() if line.strip()]
    runs = [r for r in truth if r["kind"] == "auger_run"]
    assert runs, "the auger's run never ended: it was left turning when the simulator stopped"
    assert runs[-1]["physical_g"] < 200.0, runs[-1]                 # aimed at 250 g
    # ... and booked on the way out with what the load cell saw: a clean stop leaves no intent open
    db = sqlite3.connect(f"file:{controller.db}?mode=ro", uri=True)
    try:
        feeds = db.execute("SELECT tag, phase, grams FROM feed").fetchall()
    finally:
        db.close()
    assert [(tag, phase) for tag, phase, _ in feeds] == [(runs[-1]["tag"], "done")], feeds
    assert feeds[0][2] == pytest.approx(runs[-1]["measured_g"], abs=0.05)


@pytest.mark.parametrize("controller", ["silent_device"], indirect=True)
def test_a_second_signal_ends_it_at_once(controller):
    """The first stop waits for a hung PLC's confirmations (with a deadline); the second signal
    does not wait for anything: the process ends by that signal, its simulator with it."""
    controller.reach()
    controller.send(signal.SIGTERM)
    controller.wait_log(r"SIGTERM: stopping")
    sent = controller.send(signal.SIGTERM)
    rc = controller.wait_exit(sent)
    assert rc == -signal.SIGTERM, f"exit {rc}:\n{controller.log()[-3000:]}"
    assert "controller stopped in" not in controller.log()
    assert controller.exit_s < 1.0
    controller.proc = None
    # PR_SET_PDEATHSIG: the simulator follows its parent, and init reaps it
    assert controller.wait_sim_gone(), f"simulator pid {controller.sim_pid} outlived its controller"


@pytest.mark.parametrize("controller", ["feeding"], indirect=True)
def test_a_hangup_stops_safely_though_it_signals_twice(controller):
    """A terminal that closes (an SSH session dropped) hangs up the job twice: the shell passes its
    SIGHUP on, then the kernel sends the foreground group its own. Neither is an operator asking
    twice: the stop still puts the auger safe, books the run and closes the ledger."""
    controller.reach()
    sent = controller.send(signal.SIGHUP, group=True)
    controller.send(signal.SIGHUP, group=True)
    rc = controller.wait_exit(sent)
    log = controller.log()
    assert rc == 0, f"exit {rc}:\n{log[-3000:]}"
    assert controller.exit_s < LIMIT_S and "controller stopped in" in log
    assert not controller.sim_alive() and not controller.sim_dir.exists()
    assert controller.ledger_clean() is None, controller.ledger_clean()
    assert_auger_stopped_short(controller)


@pytest.mark.parametrize("controller", ["sim_died"], indirect=True)
def test_a_dead_simulator_is_reaped_and_alarmed_at_once_and_a_restart_clears_it(controller):
    """... and alarms reload across restarts: the last simulator's death stood on a new, working
    one, and that one's death was only counted under it (no log line, no publish)."""
    controller.reach()                          # waits for the alarm the controller raises
    assert proc_state(controller.sim_pid) is None, "the dead simulator is a zombie under a live controller"
    assert controller.proc.poll() is None
    rc = controller.wait_exit(controller.send(signal.SIGTERM))
    assert rc == 0 and controller.exit_s < LIMIT_S
    controller.reach()                          # the same ledger: a new simulator, killed again
    assert len(re.findall(r"sim: simulated devices exited", controller.log())) == 2
    assert "sim: simulated devices running again" in controller.log()
    db = sqlite3.connect(f"file:{controller.db}?mode=ro", uri=True)
    try:
        rows = db.execute("SELECT active FROM alarm WHERE source = 'sim' ORDER BY id").fetchall()
    finally:
        db.close()
    assert [r[0] for r in rows] == [1, 0, 1]   # raised, cleared by the restart, raised anew
    assert controller.wait_exit(controller.send(signal.SIGTERM)) == 0


# -- retry loops, in-process: they end when the controller stops and alarm once -------------------

def absent_farm(tmp_path):
    raw = without_cleaner(tomllib.loads((ROOT / "config" / "farm.toml").read_text()))
    raw["scada"]["port"] = 0    # any free port: runs must not collide with the demo's 5020
    raw.pop("sim")
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    raw["devices"] = {
        "contacts": {"kind": "contacts", "driver": "serial", "port": str(tmp_path / "no-hub")},
        "rail": {"kind": "rail", "driver": "can", "interface": "slcan", "channel": str(tmp_path / "no-can")},
        "dispenser": {"kind": "dispenser", "driver": "modbus", "port": free_port(), "timeout_s": 0.1},
    }
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    return load_config(tmp_path / "farm.toml")


def in_process(tmp_path, monkeypatch):
    monkeypatch.setattr(app, "OPEN_BACKOFF_S", (0.005,))
    monkeypatch.setattr(hearing, "REOPEN_BACKOFF_S", (0.005,))
    cfg = absent_farm(tmp_path)
    controller = app.Controller(cfg, ScaledClock.real())
    published = []
    controller.store = Store(cfg.store.path)
    controller.alarms = Alarms(controller.store, lambda key, payload, **kw: published.append(key), controller.clock)
    controller.devices = {name: app.build_device(name, s, controller.clock, cfg.path)
                          for name, s in cfg.devices.items()}
    return controller, published


def test_open_retries_alarm_once_and_end_when_stopping(tmp_path, monkeypatch, caplog):
    controller, published = in_process(tmp_path, monkeypatch)
    caplog.set_level(logging.DEBUG, "fishfarm")

    async def main():
        opening = [asyncio.create_task(controller._open(d)) for d in controller.devices.values()]
        while sum("open attempt" in r.getMessage() for r in caplog.records) < 3 * 5:
            await asyncio.sleep(0.01)
        assert not any(t.done() for t in opening)
        controller.stopping.set()
        done, _ = await asyncio.wait(opening, timeout=1.0)       # not cancelled: they see the stop
        assert len(done) == 3 and all(t.exception() is None for t in done)

    asyncio.run(asyncio.wait_for(main(), 30))
    controller.store.close()
    assert sorted(published) == ["alarm/device/contacts", "alarm/device/dispenser", "alarm/device/rail"]


def test_contact_hub_reconnect_ends_when_stopping_without_alarming_each_retry(tmp_path, monkeypatch, caplog):
    controller, published = in_process(tmp_path, monkeypatch)
    caplog.set_level(logging.DEBUG, "fishfarm")
    hub = controller.devices["contacts"]

    async def main():
        reopening = asyncio.create_task(controller._reopen(hub))
        while sum("reconnect attempt" in r.getMessage() for r in caplog.records) < 5:
            await asyncio.sleep(0.01)
        assert not reopening.done()
        controller.stopping.set()
        done, _ = await asyncio.wait({reopening}, timeout=1.0)
        assert done and reopening.exception() is None

    asyncio.run(asyncio.wait_for(main(), 30))
    controller.store.close()
    assert published == []                   # the loss is the reader's alarm, raised once; retries are quiet
    assert controller.devices["contacts"] is hub   # nothing reopened


def test_stop_goes_on_without_a_task_that_ignores_its_cancel(tmp_path, monkeypatch):
    """Cancellation is a courtesy: a task that swallows its cancel (as asyncio.wait_for could on
    Python 3.11) is left behind, and the stop still closes the ledger."""
    controller, _ = in_process(tmp_path, monkeypatch)
    monkeypatch.setattr(shutdown, "STOP_TASKS_S", 0.05)
    cancels = []
    released = asyncio.Event()

    async def stubborn():
        while not released.is_set():
            try:
                await released.wait()
            except asyncio.CancelledError:
                cancels.append(1)              # swallowed

    async def main():
        task = asyncio.create_task(stubborn())
        controller.tasks.append(task)
        await asyncio.sleep(0)
        try:
            await asyncio.wait_for(controller.stop(), 30)
            assert not task.done() and cancels          # cancelled, and carrying on regardless
        finally:
            released.set()                     # let it end, or asyncio.run would wait for it for ever
            await task

    asyncio.run(main())
    assert controller.store.db is None                  # closed: the stop did not wait on the stubborn task


def test_the_watchdog_ends_a_stop_that_overruns(tmp_path):
    """Whatever holds the main thread, an armed watchdog ends the process with EXIT_STOP_OVERRUN."""
    code = ("import time; from controller.shutdown import StopWatchdog; "
            "w = StopWatchdog(0.1); w.arm(); time.sleep(600)")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == shutdown.EXIT_STOP_OVERRUN
    assert "stopping took longer than 0.1 s" in r.stderr


def test_the_hil_harness_fails_a_run_whose_controller_needs_sigkill(tmp_path, monkeypatch):
    from hil_tests import farm as hil

    monkeypatch.setattr(hil, "STOP_LIMIT_S", 0.3)
    h = hil.HilFarm(tmp_path, speed=1.0)
    deaf = ("import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
            "print('ready', flush=True); time.sleep(60)")
    h.ctl_proc = subprocess.Popen([sys.executable, "-c", deaf], stdout=subprocess.PIPE, text=True)
    assert h.ctl_proc.stdout.readline().strip() == "ready"      # SIGTERM is ignored from here on
    with pytest.raises(RuntimeError, match="the controller needed SIGKILL"):
        h.stop()
    assert h.ctl_proc.returncode == -signal.SIGKILL
    h.ctl_proc.stdout.close()


def _hangup_default() -> None:
    signal.signal(signal.SIGHUP, signal.SIG_DFL)      # as from a terminal, however the suite was started


def _signalled_while_importing(args: list[str], sig: int, after_s: float) -> tuple[int, str]:
    """``fishfarm ARGS`` as installed, signalled ``after_s`` after its launcher took SIGTERM (before
    that, the interpreter is still starting: its own default actions, out of any program's reach;
    the interpreter catches SIGINT from the start): (exit code, stderr)."""
    fishfarm = str(Path(sys.executable).with_name("fishfarm"))
    p = subprocess.Popen([fishfarm, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=_hangup_default)
    deadline = time.monotonic() + 10
    while not _catches(p.pid, signal.SIGTERM) and p.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.0005)
    time.sleep(after_s)
    p.send_signal(sig)
    _, err = p.communicate(timeout=30)
    assert "Traceback" not in err, err
    assert len(err.strip().splitlines()) <= 1, err       # "aborted", its own refusal, or quiet
    return p.returncode, err


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["SIGINT", "SIGTERM", "SIGHUP"])
@pytest.mark.parametrize("after_s", [0.0, 0.03, 0.1])
def test_a_signal_while_the_command_is_still_importing_is_aborted_in_one_line(tmp_path, sig, after_s):
    """``fishfarm`` as installed: a Ctrl-C in its first tenth of a second (click and the command's
    modules still importing) printed a 17-line KeyboardInterrupt traceback and exited -2. A hangup
    then (a terminal closed as it started) killed it by its default action: no word, and a
    starting controller's ledger -wal left behind (an outside tester)."""
    code, err = _signalled_while_importing(["report", "--config", str(tmp_path / "none.toml"), "--tank", "T1"],
                                           sig, after_s)
    assert code in (128 + sig, 2), (code, err)    # 2: it ran to its own refusal first


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["SIGINT", "SIGTERM", "SIGHUP"])
# (its refusal of the missing config comes by 0.1 s: a signal as it then exits meets Python's own
# finalization, which restores the default actions: -15, not one of ours)
@pytest.mark.parametrize("after_s", [0.0, 0.03])
def test_a_signal_while_the_simulator_is_still_importing_ends_it_with_0(tmp_path, sig, after_s):
    """README: a signal ends ``fishfarm sim`` whatever it is doing, exit 0. In its first second
    (imports, the command line) it exited 130, 143 or 129 as other commands do (an outside tester)."""
    code, err = _signalled_while_importing(["sim", "--config", str(tmp_path / "none.toml")], sig, after_s)
    assert code in (0, 2), (code, err)      # 2: it ran to its own refusal first


def _catches(pid: int, sig: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as fh:
            caught = next(int(line.split()[1], 16) for line in fh if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(caught >> (sig - 1) & 1)


def test_the_installed_command_takes_its_signals_before_it_imports_click():
    """Deterministically, what the timed test above samples: when ``fishfarm`` (its installed entry
    point, whatever module that names) first imports click, SIGINT and SIGTERM are already its own."""
    probe = (
        "import builtins, signal, sys\n"
        "from importlib.metadata import entry_points\n"
        "[ep] = [e for e in entry_points(group='console_scripts') if e.name == 'fishfarm']\n"
        "real, seen = builtins.__import__, []\n"
        "def spy(name, *a, **k):\n"
        "    if name == 'click' and not seen:\n"
        "        seen.append([getattr(signal.getsignal(s), '__name__', str(signal.getsignal(s)))\n"
        "                     for s in (signal.SIGINT, signal.SIGTERM)])\n"
        "    return real(name, *a, **k)\n"
        "builtins.__import__ = spy\n"
        "sys.argv = ['fishfarm', '--help']\n"
        "try:\n"
        "    ep.load()()\n"
        "except SystemExit:\n"
        "    pass\n"
        "print(seen, file=sys.stderr)\n")
    # a shell's background job (`make test &`, nohup) starts with SIGINT ignored, which the launcher
    # rightly leaves ignored: the child starts as a foreground command would, both at their defaults
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60,
                       preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen = r.stderr.strip().splitlines()[-1]
    assert seen == "[['_early', '_early']]", r.stderr


def test_a_hub_that_opens_but_stays_silent_is_reopened_quietly(tmp_path, monkeypatch, caplog):
    """A pty whose far end stalled: each reopen succeeds, its reads go silent, and it is reopened
    again every few seconds for as long as that lasts. "reconnected" at INFO each time read as a
    recovery that never was (~1,000 lines an hour): the loss and the recovery are the alarm's."""
    controller, _ = in_process(tmp_path, monkeypatch)
    caplog.set_level(logging.DEBUG, "fishfarm")

    class Opens:
        name = "contacts"

        async def open(self):
            pass

        async def close(self):
            pass
    monkeypatch.setattr(controller, "_new_driver", lambda device: Opens())

    async def main():
        for _ in range(5):
            await controller._reopen(controller.devices["contacts"])
    asyncio.run(asyncio.wait_for(main(), 30))
    controller.store.close()
    loud = [r.getMessage() for r in caplog.records if r.levelno >= logging.INFO and "contacts" in r.getMessage()]
    assert loud == [], loud
    assert sum("reopened" in r.getMessage() for r in caplog.records) == 5


def _disposition(pid: int, field: str, sig: int) -> bool:
    with open(f"/proc/{pid}/status") as fh:
        mask = next(int(line.split()[1], 16) for line in fh if line.startswith(field + ":"))
    return bool(mask >> (sig - 1) & 1)


@pytest.mark.parametrize("controller", ["feeding"], indirect=True)
def test_a_background_job_s_ignored_sigint_and_nohup_s_sighup_stay_ignored_once_it_is_up(controller, monkeypatch):
    """Started as `fishfarm run &` from a script (SIGINT ignored) under nohup (SIGHUP ignored): the
    early handlers kept both ignored, then the running controller caught them, so a Ctrl-C meant for
    the terminal was ignored while it started and stopped it once up (an outside tester). Judged
    on the kernel's own record of the process's dispositions; SIGTERM still stops it."""
    import tests.controller.shutdown_rig as rig

    def background_under_nohup() -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
    monkeypatch.setattr(rig, "as_from_a_terminal", background_under_nohup)
    controller.reach()                                    # up, serving, its auger running
    pid = controller.proc.pid
    assert _disposition(pid, "SigIgn", signal.SIGINT) and _disposition(pid, "SigIgn", signal.SIGHUP)
    assert _disposition(pid, "SigCgt", signal.SIGTERM)
    sim = controller.sim_pid
    assert sim is not None and _disposition(sim, "SigIgn", signal.SIGINT)
    assert _disposition(sim, "SigCgt", signal.SIGTERM)
    rc = controller.wait_exit(controller.send(signal.SIGTERM))
    assert rc == 0 and "controller stopped in" in controller.log(), controller.log()[-3000:]


_DROPPED_IN = {
    "__del__": "class Dropped:\n    def __del__(self):\n        signal.raise_signal(SIG)\nDropped()\n",
    "weakref callback": ("class Held:\n    pass\nheld = Held()\n"
                         "ref = weakref.ref(held, lambda _ref: signal.raise_signal(SIG))\ndel held\n"),
}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["SIGINT", "SIGTERM", "SIGHUP"])
@pytest.mark.parametrize("where", sorted(_DROPPED_IN))
def test_a_signal_taken_where_python_cannot_raise_still_ends_the_command(sig, where):
    """A SIGHUP as ``report`` imported its modules met the import machinery's module-lock weakref
    callback: its SystemExit was printed as "Exception ignored" with a traceback, and lost; the
    command ran on to its end (CI). The signal is taken again at the next line that can raise."""
    code = ("import signal, sys, time, weakref\n"
            "from controller.cli import take_signals\n"
            f"SIG = {int(sig)}\n"
            # as from a terminal, however the suite was started (nohup, a background job)
            "signal.signal(signal.SIGHUP, signal.SIG_DFL)\n"
            "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "take_signals()\n"
            "try:\n"
            + "".join(f"    {line}\n" for line in _DROPPED_IN[where].splitlines())
            + "    deadline = time.monotonic() + 30\n"     # (it comes back within a switch interval)
            "    while time.monotonic() < deadline:\n"
            "        pass\n"
            "    print('ran on', flush=True)\n"
            "except KeyboardInterrupt:\n"
            "    sys.exit(130)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert (r.returncode, r.stdout, r.stderr) == (128 + sig, "", "")


def test_other_exceptions_where_python_cannot_raise_are_still_reported():
    code = ("from controller.cli import take_signals\n"
            "take_signals()\n"
            "class Broken:\n    def __del__(self):\n        raise ValueError('in __del__')\n"
            "Broken()\n"
            "print('ran on', flush=True)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert (r.returncode, r.stdout) == (0, "ran on\n")
    assert "Exception ignored in" in r.stderr and "ValueError: in __del__" in r.stderr


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_signal_whose_exception_another_replaced_still_ends_the_command_as_that_signal(tmp_path, sig):
    """A SIGHUP as a survey imported its modules: its SystemExit raised inside an extension's
    initialisation, which replaced it with 'ImportError: initialization failed' (pybind11's, and
    OpenCV's, do): 'fishfarm: internal error', exit 1."""
    (tmp_path / "replacing_cmd.py").write_text(
        "import os, signal\nimport click\n"
        "try:\n    signal.raise_signal(int(os.environ['SIGNAL']))\n"
        "except BaseException:\n    raise ImportError('initialization failed') from None\n"
        "@click.command()\ndef replacing():\n    print('ran on')\n")
    code = ("import signal, sys\n"
            "from controller import cli\n"
            "signal.signal(signal.SIGHUP, signal.SIG_DFL)\n"       # as from a terminal (above)
            "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "cli.COMMANDS['replacing'] = 'replacing_cmd:replacing'\n"
            "cli.take_signals()\n"
            "sys.exit(cli.main(['replacing']))\n")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}", "SIGNAL": str(int(sig))}
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60, env=env)
    assert (r.returncode, r.stdout, r.stderr) == (128 + sig, "", "")
