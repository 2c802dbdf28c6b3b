"""The real ``fishfarm run`` process, brought to a phase of its life and stopped by a signal.

Shared by tests/controller/test_shutdown.py and bench/bench_shutdown.py. Each phase is a config
on free ports in its own directory plus a way to reach that phase, judged from the controller's
own log lines (it logs what it is doing), never by sleeping for luck.
"""
from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import tomli_w

from hil_tests.farm import without_cleaner  # the demo farm's feeder alone
from hil_tests.ports import free_port

ROOT = Path(__file__).resolve().parents[2]
SIM_PID = re.compile(r"fishfarm sim, pid (\d+)")
PHASES = ("starting", "absent_device", "silent_device", "feeding", "sim_died")


def proc_start(pid: int) -> str | None:
    """The process's start time (clock ticks since boot), None when no such process (nor zombie)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[19]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return None


def proc_state(pid: int) -> str | None:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return None


class SilentPlc:
    """A TCP server that accepts Modbus connections and never answers: a PLC that hung."""

    def __init__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.port = self.sock.getsockname()[1]
        self.conns: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)

    def close(self):
        with contextlib.suppress(OSError):          # wakes the accept thread: close alone leaves it waiting
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        for conn in self.conns:
            conn.close()


def as_from_a_terminal() -> None:
    """SIGINT and SIGHUP at their defaults in the child, however this run was started: a shell's
    background job (`make test &`) ignores SIGINT, nohup SIGHUP, and an ignored signal stays
    ignored through exec — the controller keeps it so."""
    for sig in (signal.SIGHUP, signal.SIGINT):
        signal.signal(sig, signal.SIG_DFL)


class RunningController:
    def __init__(self, workdir: Path, phase: str, *, speed: float = 1.0):
        self.dir = Path(workdir)
        self.phase = phase
        self.db = self.dir / "ledger.db"
        self.log_path = self.dir / "controller.log"
        self.truth = self.dir / "truth.jsonl"
        self.zenoh = f"tcp/127.0.0.1:{free_port()}"
        self.silent: SilentPlc | None = None
        raw = without_cleaner(tomllib.loads((ROOT / "config" / "farm.toml").read_text()))
        raw["scada"]["port"] = 0    # any free port: runs must not collide with the demo's 5020
        raw["bus"] = {"mode": "peer", "listen": [self.zenoh], "connect": []}
        raw["store"] = {"path": str(self.db)}
        raw["devices"]["dispenser"]["port"] = 0
        raw["feeding"]["portion_g"] = 300            # an operator's long auger run, to stop midway
        if phase == "absent_device":                   # nothing answers anywhere: waits, retrying
            raw.pop("sim")
            raw["devices"] = {
                "contacts": {"kind": "contacts", "driver": "serial", "port": str(self.dir / "no-hub")},
                "rail": {"kind": "rail", "driver": "can", "interface": "slcan", "channel": str(self.dir / "no-can")},
                "dispenser": {"kind": "dispenser", "driver": "modbus", "port": free_port(), "timeout_s": 0.2},
            }
        elif phase == "silent_device":                 # the dispenser's PLC takes the connection, then hangs
            self.silent = SilentPlc()
            raw["devices"]["dispenser"] = {"kind": "dispenser", "driver": "modbus", "port": self.silent.port}
        self.config = self.dir / "farm.toml"
        self.config.write_text(tomli_w.dumps(raw))
        self.speed = speed if phase not in ("absent_device", "silent_device") else 1.0
        self.proc: subprocess.Popen | None = None
        self.sim_pid: int | None = None
        self.sim_dir: Path | None = None
        self.sim_start: str | None = None
        self.exit_s: float | None = None
        self.starts = 0                        # on this ledger and log

    # -- the process ----------------------------------------------------------
    def start(self) -> None:
        self.starts += 1
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "FISHFARM_SIM_TRUTH": str(self.truth)}
        with open(self.log_path, "ab") as log:
            # a session of its own: a signal to its process group is what a terminal's Ctrl-C sends
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "controller.cli", "run", "--config", str(self.config), "--no-console",
                 "--speed", repr(self.speed)],
                cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True,
                preexec_fn=as_from_a_terminal)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def wait_log(self, pattern: str, timeout_s: float = 30.0, count: int = 1) -> None:
        deadline = time.monotonic() + timeout_s
        while len(re.findall(pattern, self.log())) < count:
            if self.proc.poll() is not None:
                raise AssertionError(f"controller exited {self.proc.returncode} before /{pattern}/:\n{self.log()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"no /{pattern}/ in {timeout_s} s:\n{self.log()[-3000:]}")
            time.sleep(0.01)

    def note_sim(self) -> None:
        self.wait_log(SIM_PID.pattern, count=self.starts)          # this start's (a restart's log holds the last's)
        self.sim_pid = int(SIM_PID.findall(self.log())[-1])
        self.sim_start = proc_start(self.sim_pid)
        with open(f"/proc/{self.sim_pid}/cmdline", "rb") as fh:     # its files' directory
            args = fh.read().decode().split("\0")
        self.sim_dir = Path(args[args.index("--endpoints") + 1]).parent

    def wait_sim_gone(self, timeout_s: float = 5.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while self.sim_alive():
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    def leftovers(self) -> list[int]:
        """Processes still running this farm's config (its simulator, say): none once it stopped."""
        mark = str(self.config).encode()
        found = []
        for entry in os.listdir("/proc"):
            if entry.isdigit():
                try:
                    with open(f"/proc/{entry}/cmdline", "rb") as fh:
                        if mark in fh.read():
                            found.append(int(entry))
                except OSError:
                    pass
        return found

    def sim_alive(self) -> bool:
        """The simulator child still exists, running or as a zombie (same pid, same start time)."""
        return self.sim_pid is not None and self.sim_start is not None and proc_start(self.sim_pid) == self.sim_start

    def reach(self) -> None:
        """Bring the controller to its phase."""
        self.start()
        if self.phase == "starting":
            self.note_sim()                        # the simulator is starting: nothing is up yet
        elif self.phase == "absent_device":
            self.wait_log(r"device/\w+: cannot open", count=3)
        elif self.phase == "silent_device":
            self.note_sim()
            self.wait_log(r"controller for site")
        elif self.phase == "feeding":
            self.note_sim()
            self.wait_log(r"feeder: idle")
            self._operator_feed("T1", 250.0)
            self.wait_log(r"feeder: dispensing")
            self.wait_auger_running()
        elif self.phase == "sim_died":
            self.note_sim()
            self.wait_log(r"controller for site", count=self.starts)
            os.kill(self.sim_pid, signal.SIGKILL)          # what a Ctrl-C did to it when it shared our group
            self.wait_log(r"sim: simulated devices exited", count=self.starts)
        else:
            raise ValueError(self.phase)

    def _operator_feed(self, tank: str, grams: float) -> None:
        from controller.bus import Bus

        client = Bus.client(self.zenoh, timeout_s=10.0)
        try:
            [reply] = client.query("override/feed", {"tank": tank, "grams": grams, "operator": "test"})
        finally:
            client.close()
        assert reply.get("ok"), reply

    def wait_auger_running(self, timeout_s: float = 30.0) -> None:
        """Until the simulated PLC has accepted a START: the auger turns. (An open intent is not
        enough: a stop between the intent and its START rightly leaves the auger still.)"""
        deadline = time.monotonic() + timeout_s
        while not (self.truth.exists() and '"auger_start"' in self.truth.read_text()):
            assert time.monotonic() < deadline, f"no auger run in {timeout_s} s:\n{self.log()[-3000:]}"
            time.sleep(0.01)

    def send(self, sig: int, group: bool = False) -> float:
        """SIGINT as a terminal sends it (to the whole foreground group), SIGTERM as a service
        manager does (to the process); ``group``: to the group whatever the signal (a hangup).
        Returns the monotonic time it was sent."""
        if sig == signal.SIGINT or group:
            os.killpg(self.proc.pid, sig)
        else:
            self.proc.send_signal(sig)
        return time.monotonic()

    def wait_exit(self, sent: float, timeout_s: float = 15.0) -> int:
        """Wait for the exit (SIGKILL past ``timeout_s``); records ``exit_s`` from ``sent``."""
        try:
            rc = self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.kill()
            tail = self.log()[-3000:]
            raise AssertionError(f"controller still alive {timeout_s} s after the signal:\n{tail}") from None
        self.exit_s = time.monotonic() - sent
        return rc

    def kill(self) -> None:
        """Leave nothing behind, whatever happened."""
        if self.proc is not None and self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait()
        if self.sim_alive():
            os.kill(self.sim_pid, signal.SIGKILL)
        for pid in self.leftovers():
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        if self.silent is not None:
            self.silent.close()

    # -- evidence -------------------------------------------------------------
    def ledger_clean(self) -> str | None:
        """None when the ledger was closed cleanly (no write-ahead log left, integrity ok)."""
        if not self.db.exists():
            return "no ledger"
        for leftover in (Path(f"{self.db}-wal"), Path(f"{self.db}-shm")):
            if leftover.exists():
                return f"{leftover.name} left behind ({leftover.stat().st_size} bytes): not closed cleanly"
        db = sqlite3.connect(f"file:{self.db}?mode=ro", uri=True)
        try:
            verdict = db.execute("PRAGMA integrity_check").fetchone()[0]
        finally:
            db.close()
        return None if verdict == "ok" else f"integrity_check: {verdict}"
