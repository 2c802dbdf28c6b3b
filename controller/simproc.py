"""The child process that serves a config's simulated devices (``fishfarm sim``).

It shares the controller's timeline (same epoch and speed) and dies with the controller
(PR_SET_PDEATHSIG), so a killed controller never leaves a farm simulator behind.
"""
from __future__ import annotations

import asyncio
import ctypes
import json
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from controller.errors import BadInput

STARTUP_TIMEOUT_S = 30.0


def _die_with_parent() -> None:
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


class SimProcess:
    def __init__(self, cfg, clock):
        self.cfg, self.clock = cfg, clock
        self.proc: subprocess.Popen | None = None
        self._dir = tempfile.TemporaryDirectory(prefix="fishfarm-sim-")

    async def start(self) -> dict[str, dict]:
        """Start the simulator; return the real-driver section of every simulated device."""
        endpoints = Path(self._dir.name) / "endpoints.json"
        args = [sys.executable, "-m", "controller.cli", "sim", "--config", self.cfg.path,
                "--endpoints", str(endpoints), *self.clock.as_args()]
        truth = os.environ.get("FISHFARM_SIM_TRUTH")
        if truth:
            args += ["--truth", truth]
        self.proc = subprocess.Popen(args, preexec_fn=_die_with_parent)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + STARTUP_TIMEOUT_S
        while not endpoints.exists():
            if self.proc.poll() is not None:       # it said why on stderr, in one line
                raise BadInput(self.cfg.path, "devices",
                               f"the simulated devices did not start (fishfarm sim exited {self.proc.returncode})")
            if loop.time() > deadline:
                raise RuntimeError("the farm simulator did not start")
            await asyncio.sleep(0.05)
        return json.loads(endpoints.read_text())

    async def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                await asyncio.to_thread(self.proc.wait, 5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self._dir.cleanup()
