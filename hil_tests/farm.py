"""Hardware-in-loop harness: a simulated farm process and the real controller process.

The simulator (``fishfarm sim``) serves the devices over their real protocols (contact hub
on a pty, rail drive over slcan on a pty, dispenser as a Modbus TCP server) and writes the
ground truth. The controller (``fishfarm run``) is configured with the *real* drivers
pointed at those endpoints, exactly as on a farm, and shares the simulator's timeline
through the clock epoch. The harness can SIGKILL and restart the controller at will.
"""
from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import tomli_w

from hil_tests.ports import free_port
from hil_tests.stalls import StallWitness

ROOT = Path(__file__).resolve().parents[1]
CLEANER_KINDS = ("thrusters", "tower_camera")
CLEANER_SIM = ("pond", "thrusters", "tower_camera")
SURVEY_KINDS = ("stereo_camera",)
FARM_START = 1_780_016_400.0          # 2026-05-29 01:00 UTC = 02:00 local (utc_offset_h = 1)
STOP_LIMIT_S = 10.0                   # the controller ends within 5 s of SIGTERM; slack for a loaded machine


def merge(base: dict, extra: dict) -> dict:
    out = dict(base)
    for key, value in extra.items():
        both = isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = merge(out[key], value) if both else value
    return out


def without_cleaner(config: dict, surveys: bool = False) -> dict:
    """The farm's feeder alone, without its pond cleaner and its survey cameras: the feeder's runs go
    at hundreds of times the wall, where a camera's frames are farm minutes apart, and rendering
    would only take their CPU (and a scheduled survey would move the robot those runs time).
    ``surveys``: keep the survey cameras, schedules and the fish's feeding hours (a grow-out)."""
    out = {k: v for k, v in config.items() if k != "cleaning"}
    out["devices"] = {n: s for n, s in config.get("devices", {}).items() if s.get("kind") not in CLEANER_KINDS}
    if "sim" in config:
        out["sim"] = {k: v for k, v in config["sim"].items() if k not in CLEANER_SIM}
    if surveys:
        return out
    out = without_surveys(out)
    if "sim" in out:      # the feeder's runs judge feeding over their whole span: fish ask round the clock
        out["sim"]["fish"] = {k: v for k, v in out["sim"].get("fish", {}).items() if k != "feeding_hours"}
    return out


def without_surveys(config: dict) -> dict:
    """The farm without its survey cameras and schedules (a cleaning run: their rendering would take
    the CPU the tower camera's frames need, and a survey is not the run's subject)."""
    out = {k: v for k, v in config.items() if k != "surveys"}
    out["devices"] = {n: s for n, s in config.get("devices", {}).items() if s.get("kind") not in SURVEY_KINDS}
    if "sim" in config:
        out["sim"] = {k: v for k, v in config["sim"].items() if k not in SURVEY_KINDS}
    if "tanks" in config:
        out["tanks"] = [{k: v for k, v in t.items() if k != "survey"} for t in config["tanks"]]
    return out


class HilFarm:
    def __init__(self, workdir: Path, *, speed: float, overrides: dict | None = None,
                 base_config: Path = ROOT / "config" / "farm.toml", farm_start: float = FARM_START,
                 cleaner: bool = False, surveys: bool = False, elastic: tuple[float, float] | None = None):
        """``elastic``: (slow, fast) speeds of an elastic clock (devices/elastic_clock.py) shared
        by the processes through a file in ``workdir``, instead of a constant ``speed``."""
        self.dir = Path(workdir)
        self.speed = speed
        self.witness = StallWitness().start()  # the machine's own stalls, to tell from the controller's
        self.epoch_wall = time.time() + 1.0
        self.epoch_farm = farm_start
        self.clock = self.watch = None
        if elastic is not None:
            from devices.elastic_clock import ElasticClock, create
            from hil_tests.clock_watch import ClockWatch
            self.dir.mkdir(parents=True, exist_ok=True)
            create(self.dir / "clock", slow=elastic[0], fast=elastic[1], farm_start=farm_start,
                   awaited=("sim", "controller"))
            self.clock = ElasticClock(self.dir / "clock")
            self.watch = ClockWatch(self.clock).start()
        base = tomllib.loads(base_config.read_text())
        if not cleaner:
            base = without_cleaner(base, surveys=surveys)
        elif not surveys:
            base = without_surveys(base)
        self.config = merge(base, overrides or {})
        tank_ids = {t["id"] for t in self.config.get("tanks", [])}
        for section in self.config.get("devices", {}).values():
            if section.get("kind") == "dispenser":
                section["port"] = 0            # any free port: runs must not collide with the demo
            if isinstance(section.get("probes"), dict):   # a farm of other tanks: the demo's probes of its own go
                section["probes"] = {k: v for k, v in section["probes"].items() if k == "supply" or k in tank_ids}
        self.sim_proc: subprocess.Popen | None = None
        self.ctl_proc: subprocess.Popen | None = None
        self.workers: list[subprocess.Popen] = []
        self.restarts = 0
        self.stop_s: float | None = None       # wall seconds the controller took to stop on SIGTERM
        self.truth_path = self.dir / "truth.jsonl"
        self.db_path = self.dir / "ledger.db"
        self.zenoh_port = free_port()
        self.scada_port = free_port()
        if "scada" in self.config:            # the SCADA server too: never the demo's 5020
            self.config["scada"]["port"] = self.scada_port

    # -- clock ----------------------------------------------------------------
    def clock_args(self) -> list[str]:
        if self.clock is not None:
            return self.clock.as_args()
        return ["--speed", repr(self.speed), "--epoch-wall", repr(self.epoch_wall),
                "--epoch-farm", repr(self.epoch_farm)]

    def hear_args(self) -> list[str]:
        """On an elastic clock the simulator hears the controller's demands: fish it has heard hold
        the clock no longer (devices/sim/pace.py)."""
        return ["--hear", f"tcp/127.0.0.1:{self.zenoh_port}"] if self.clock is not None else []

    def farm_now(self) -> float:
        if self.clock is not None:
            return self.clock.now()
        return self.epoch_farm + (time.time() - self.epoch_wall) * self.speed

    def sleep_until_farm(self, t: float) -> None:
        while (now := self.farm_now()) < t:
            self.check_alive()
            time.sleep(min(0.2, (t - now) / self.speed if self.clock is None else self.clock.wall(t - now)))

    # -- processes ------------------------------------------------------------
    def _spawn(self, args: list[str], log_name: str) -> subprocess.Popen:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        with open(self.dir / log_name, "ab") as log:     # the child keeps its own copy of the descriptor
            return subprocess.Popen([sys.executable, "-m", "controller.cli", *args], cwd=ROOT, stdout=log,
                                    stderr=subprocess.STDOUT, env=env)

    def start_sim(self, timeout_s: float = 30.0) -> dict:
        sim_cfg = self.dir / "sim.toml"
        sim_cfg.write_text(tomli_w.dumps(self.config))
        endpoints = self.dir / "endpoints.json"
        self.sim_proc = self._spawn(["sim", "--config", str(sim_cfg), "--endpoints", str(endpoints),
                                     "--truth", str(self.truth_path), *self.clock_args(), *self.hear_args()],
                                    "sim.log")
        deadline = time.time() + timeout_s
        while not endpoints.exists():
            if self.sim_proc.poll() is not None or time.time() > deadline:
                raise RuntimeError(f"simulator did not start:\n{self.log('sim.log')}")
            time.sleep(0.05)
        self.endpoints = json.loads(endpoints.read_text())
        ctl = dict(self.config)
        ctl["devices"] = {name: self.endpoints[name] for name in self.config["devices"]}
        ctl["bus"] = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{self.zenoh_port}"], "connect": []}
        ctl["store"] = {"path": str(self.db_path)}
        ctl.pop("sim", None)
        (self.dir / "controller.toml").write_text(tomli_w.dumps(ctl))
        return self.endpoints

    def start_controller(self) -> None:
        self.ctl_proc = self._spawn(["run", "--config", str(self.dir / "controller.toml"), "--no-console",
                                     *self.clock_args()], "controller.log")

    def start_workers(self, n: int, timeout_s: float = 60.0) -> None:
        """``n`` vision workers (``fishfarm worker``), separate processes reaching the controller's
        Zenoh endpoint as a farm's would: the survey stops measure their pairs there. Returns once
        each has loaded (it says so, retrying until the controller listens): started before the
        farm, their imports do not starve its first minutes on a fast clock."""
        for i in range(n):
            self.workers.append(self._spawn(["worker", "--connect", f"tcp/127.0.0.1:{self.zenoh_port}",
                                             "--site", self.config.get("site", "demo"), "--id", f"hil-{i}"],
                                            f"worker-{i}.log"))
        deadline = time.time() + timeout_s
        while not all(self.log(f"worker-{i}.log") for i in range(n)):
            self.check_alive()
            if time.time() > deadline:
                raise RuntimeError("vision workers did not start")
            time.sleep(0.05)

    def wait_controller_up(self, timeout_s: float = 60.0) -> float:
        """Wait until the controller says it is up; returns the farm time it was seen."""
        deadline = time.time() + timeout_s
        mark = self.restarts
        while True:
            self.check_alive()
            if self.log("controller.log", tail=10_000).count("controller for site") > mark:
                return self.farm_now()
            if time.time() > deadline:
                raise RuntimeError(f"controller did not come up:\n{self.log('controller.log')}")
            time.sleep(0.02)

    def start_farm(self) -> float:
        """The simulator, then the controller; the farm time the controller was seen up."""
        self.start_sim()
        self.start_controller()
        return self.wait_controller_up()

    def tool(self, *args: str, timeout_s: float | None = None) -> tuple[int, dict]:
        """An operator's command line against this farm's controller (its own default timeout, 2 s,
        unless ``timeout_s``): (exit status, its JSON, or its output where it printed none)."""
        wait = [] if timeout_s is None else ["--timeout", str(timeout_s)]
        r = subprocess.run([str(Path(sys.executable).with_name("fishfarm")), *args, "--connect",
                            f"tcp/127.0.0.1:{self.zenoh_port}", *wait], capture_output=True, text=True, timeout=60)
        try:
            return r.returncode, json.loads(r.stdout)
        except ValueError:
            return r.returncode, {"stdout": r.stdout, "stderr": r.stderr}

    def kill_controller(self, sig: int = signal.SIGKILL) -> None:
        self.ctl_proc.send_signal(sig)
        self.ctl_proc.wait(timeout=30)
        self.restarts += 1

    def check_alive(self) -> None:
        """Both processes run; a controller this harness killed (and has not restarted) is not missed."""
        killed = self.ctl_proc is not None and self.ctl_proc.returncode == -signal.SIGKILL
        workers = [(f"worker-{i}", w) for i, w in enumerate(self.workers)]
        for name, proc in (("sim", self.sim_proc), ("controller", None if killed else self.ctl_proc), *workers):
            if proc is not None and proc.poll() is not None:
                raise RuntimeError(f"{name} exited with {proc.returncode}:\n{self.log(name + '.log')}")

    def stop(self) -> None:
        """SIGTERM the controller, then the simulator. The run fails when the controller does not
        end by itself within STOP_LIMIT_S (it is then SIGKILLed) or ends with anything but 0 (70:
        its own watchdog had to cut the stop short): stop means stop, in every HIL run."""
        problem = None
        if self.ctl_proc is not None and self.ctl_proc.poll() is None:
            sent = time.monotonic()
            self.ctl_proc.send_signal(signal.SIGTERM)
            try:
                rc = self.ctl_proc.wait(timeout=STOP_LIMIT_S)
            except subprocess.TimeoutExpired:
                self.ctl_proc.kill()
                self.ctl_proc.wait()
                problem = f"the controller needed SIGKILL: still running {STOP_LIMIT_S:g} s after SIGTERM"
            else:
                self.stop_s = time.monotonic() - sent
                if rc != 0:
                    problem = f"the controller exited {rc} on SIGTERM, after {self.stop_s:.2f} s"
        for proc in self.workers:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in self.workers:
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self.sim_proc is not None and self.sim_proc.poll() is None:
            self.sim_proc.send_signal(signal.SIGTERM)
            try:
                self.sim_proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.sim_proc.kill()
                self.sim_proc.wait()
        self.witness.stop()
        if self.watch is not None:
            self.watch.stop()
        if problem is not None:
            raise RuntimeError(f"{problem}:\n{self.log('controller.log')}")

    def stalls(self) -> list[tuple[float, float]]:
        """Farm spans in which the machine stood still (hil_tests/stalls.py)."""
        if self.watch is not None:      # an elastic clock: through the samples of its timeline
            return [(self.watch.farm_at(a), self.watch.farm_at(b)) for a, b in self.witness.spans]
        return self.witness.farm_spans(self.epoch_wall, self.epoch_farm, self.speed)

    def log(self, name: str, tail: int = 60) -> str:
        path = self.dir / name
        if not path.exists():
            return ""
        return "\n".join(path.read_text(errors="replace").splitlines()[-tail:])

    # -- evidence -------------------------------------------------------------
    def ledger(self) -> sqlite3.Connection:
        db = sqlite3.connect(f"file:{self.db_path}?mode=ro", uri=True)
        db.row_factory = sqlite3.Row
        return db

    def truth(self) -> list[dict]:
        with open(self.truth_path, encoding="utf-8") as fh:
            return [json.loads(line) for line in fh if line.strip()]
