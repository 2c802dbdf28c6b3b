"""The child process that serves a config's simulated devices (``fishfarm sim``).

It shares the controller's timeline (same epoch and speed). It runs in a session of its own, so
a terminal's Ctrl-C reaches the controller only: the controller puts its actuators safe first,
then stops the child (SIGTERM, then SIGKILL) and reaps it. It dies with the controller
(PR_SET_PDEATHSIG), so even a SIGKILLed controller never leaves a farm simulator behind; the
directory of its files, which a killed controller cannot remove, the next controller's start does.
"""
from __future__ import annotations

import asyncio
import contextlib
import ctypes
import fcntl
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from controller.errors import BadInput

log = logging.getLogger("fishfarm.sim")

STARTUP_TIMEOUT_S = 30.0
TERM_WAIT_S = 1.5           # wall seconds for the simulator to end on SIGTERM before SIGKILL
KILL_WAIT_S = 0.4


def _dying_with(parent: int):
    def die_with_parent() -> None:          # in the child, between fork and exec
        try:
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
        except OSError:
            pass
        if os.getppid() != parent:          # the parent died before the prctl took: follow it now
            os._exit(1)
    return die_with_parent


DIR_PREFIX = "fishfarm-sim-"
OWNER_LOCK = "owner.lock"   # flock()ed by the controller that made the directory, for its lifetime


def sweep_leftovers(tmp: str | None = None) -> list[Path]:
    """Remove the simulator directories of controllers that are gone (killed outright: SIGKILL, a
    second signal, the stop watchdog); return them. Their owner's lock is the kernel's, released
    when the process ends however it ends: a directory whose lock this process can take has no
    owner left. A directory without a lock (being made, or made by an older version) is left."""
    removed = []
    base = Path(tmp or tempfile.gettempdir())
    try:
        candidates = sorted(base.glob(DIR_PREFIX + "*"))
    except OSError:
        return removed
    for path in candidates:
        try:
            if path.is_symlink() or not path.is_dir() or path.stat().st_uid != os.getuid():
                continue
            fd = os.open(path / OWNER_LOCK, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)                            # its controller is alive
            continue
        try:
            shutil.rmtree(path)
            removed.append(path)
        except OSError as exc:
            log.debug("simulator directory %s not removed: %s", path, exc)
        finally:
            os.close(fd)
    if removed:
        log.info("removed %d simulator director%s left by controllers that were killed",
                 len(removed), "y" if len(removed) == 1 else "ies")
    return removed


def _owned_dir() -> tuple[Path, int]:
    """A new simulator directory, locked by this process (the lock file is made and locked under
    another name, then renamed: a sweep never sees it unlocked)."""
    path = Path(tempfile.mkdtemp(prefix=DIR_PREFIX))
    fd = os.open(path / (OWNER_LOCK + ".new"), os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
    fcntl.flock(fd, fcntl.LOCK_EX)
    os.rename(path / (OWNER_LOCK + ".new"), path / OWNER_LOCK)
    return path, fd


class SimProcess:
    def __init__(self, cfg, clock):
        self.cfg, self.clock = cfg, clock
        self.proc: subprocess.Popen | None = None
        sweep_leftovers()
        self.dir, self._lock_fd = _owned_dir()

    def remove_dir(self) -> None:
        """The directory and its files removed, its lock let go (once; safe from any thread)."""
        shutil.rmtree(self.dir, ignore_errors=True)
        fd, self._lock_fd = self._lock_fd, -1
        if fd >= 0:
            with contextlib.suppress(OSError):
                os.close(fd)

    async def start(self) -> dict[str, dict]:
        """Start the simulator; return the real-driver section of every simulated device."""
        endpoints = self.dir / "endpoints.json"
        args = [sys.executable, "-m", "controller.launch", "sim", "--config", self.cfg.path,
                "--endpoints", str(endpoints), *self.clock.as_args()]
        truth = os.environ.get("FISHFARM_SIM_TRUTH")
        if truth:
            args += ["--truth", truth]
        self.proc = subprocess.Popen(args, start_new_session=True, preexec_fn=_dying_with(os.getpid()))
        log.info("simulated devices: fishfarm sim, pid %d", self.proc.pid)
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

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def poll(self) -> int | None:
        """The child's exit code once it has exited (and reaped: no zombie), else None."""
        return None if self.proc is None else self.proc.poll()

    def kill(self) -> None:
        """SIGKILL, no waiting: for a process that is about to end itself."""
        if self.proc is not None and self.proc.returncode is None:
            try:
                self.proc.kill()
            except OSError:
                pass

    async def stop(self) -> None:
        """SIGTERM, SIGKILL after TERM_WAIT_S, reaped; at most TERM_WAIT_S + KILL_WAIT_S."""
        try:
            if self.proc is not None and self.proc.poll() is None:
                self.proc.terminate()
                if not await self._ended(TERM_WAIT_S):
                    log.warning("fishfarm sim (pid %d) ignored SIGTERM for %g s: killing it",
                                self.proc.pid, TERM_WAIT_S)
                    self.proc.kill()
                    if not await self._ended(KILL_WAIT_S):
                        log.error("fishfarm sim (pid %d) survived SIGKILL for %g s", self.proc.pid, KILL_WAIT_S)
            if self.proc is not None and self.proc.returncode is not None:
                log.info("simulated devices stopped (exit %d)", self.proc.returncode)
        finally:
            self.remove_dir()

    async def _ended(self, wall_s: float) -> bool:
        # polled, not proc.wait() on a thread: a thread blocked in wait() would outlive a stop
        loop = asyncio.get_running_loop()
        deadline = loop.time() + wall_s
        while self.proc.poll() is None:
            if loop.time() >= deadline:
                return False
            await asyncio.sleep(0.02)
        return True
