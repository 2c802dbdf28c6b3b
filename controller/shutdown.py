"""Stopping the controller process: deadlines for every step, a watchdog, the signal handlers.

"Stop means stop": SIGINT, SIGTERM or SIGHUP ends ``fishfarm run`` within HARD_STOP_S from any state. Each
step of ``Controller.stop`` is bounded by the deadlines below, and a task that ignores its cancel
(on Python 3.11 ``asyncio.wait_for`` can swallow one, gh-86296) is left behind, not waited for;
the watchdog ends the process if even that overruns. A second SIGINT or SIGTERM gets the default action.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import socket
import threading
import time

log = logging.getLogger("fishfarm")

# Stopping (wall seconds). Each step has its own deadline; together they stay well inside
# HARD_STOP_S, after which the watchdog ends the process whatever it is doing.
STOP_TASKS_S = 0.75         # for cancelled tasks to end; one that ignores its cancel is left behind
SAFE_COMMAND_S = 0.5        # for each actuator to confirm auger off / gate closed / drive stopped
SETTLE_S = 0.5              # to book a run the stop cut short from the dispenser's counters
CLOSE_DEVICE_S = 0.5
CLOSE_BUS_S = 1.0
SIM_STOP_S = 2.0            # SimProcess.stop's own SIGTERM-then-SIGKILL fits in this
HARD_STOP_S = 4.5           # from the first signal to the process's end, at the very latest
EXIT_STOP_OVERRUN = 70      # the watchdog cut a stop short (EX_SOFTWARE)


async def ended(tasks, seconds: float, what: str) -> bool:
    """Wait at most ``seconds`` for ``tasks``; cancel and leave behind those still running."""
    if not tasks:
        return True
    done, pending = await asyncio.wait(tasks, timeout=seconds)
    for task in done:
        if not task.cancelled() and task.exception() is not None:
            log.debug("stopping: %s ended with %r", what, task.exception())
    for task in pending:
        task.cancel()
        log.warning("stopping: %s %s did not end in %g s; going on without it", what,
                    getattr(task.get_coro(), "__qualname__", task.get_name()), seconds)
    return not pending


async def in_thread(fn, seconds: float) -> bool:
    """Run a blocking ``fn`` on a daemon thread for at most ``seconds``; True when it finished.
    A daemon thread, so one that never returns cannot hold the process's exit either."""
    loop = asyncio.get_running_loop()
    finished = loop.create_future()

    def done(_=None):
        if not finished.done():
            finished.set_result(None)

    def work():
        try:
            fn()
        except Exception:
            log.exception("stopping: %s failed", getattr(fn, "__qualname__", fn))
        finally:
            with contextlib.suppress(RuntimeError):       # the loop may be gone already
                loop.call_soon_threadsafe(done)

    threading.Thread(target=work, name="fishfarm-stop", daemon=True).start()
    ready, _ = await asyncio.wait({finished}, timeout=seconds)
    return bool(ready)


class StopWatchdog:
    """The last line of "stop means stop": once armed, a thread of its own ends the process after
    ``budget_s`` wall seconds, however stuck the event loop is. Arming is one write to a pipe, safe
    from a signal handler (no lock taken)."""

    def __init__(self, budget_s: float = HARD_STOP_S, on_overrun=None, who: str = "fishfarm"):
        self.budget_s, self.on_overrun, self.who = budget_s, on_overrun, who
        self._r, self._w = os.pipe()
        threading.Thread(target=self._watch, name="fishfarm-stop-watchdog", daemon=True).start()

    def arm(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._w, b"!")

    def _watch(self) -> None:
        os.read(self._r, 1)
        time.sleep(self.budget_s)
        try:
            if self.on_overrun is not None:
                self.on_overrun()
        finally:
            os.write(2, b"%s: stopping took longer than %g s: exiting at once (code %d)\n"
                     % (self.who.encode(), self.budget_s, EXIT_STOP_OVERRUN))
            os._exit(EXIT_STOP_OVERRUN)


def install_signal_handlers(controller) -> None:
    """SIGINT/SIGTERM/SIGHUP stop the controller (actuators safe, ledger closed) within HARD_STOP_S;
    the first one restores SIGINT's and SIGTERM's default action, so a second one of those ends the
    process at once, whatever it is doing. SIGHUP (a closed terminal, a dropped SSH session) is
    handled like SIGTERM but never becomes a second signal: a hangup comes twice (the shell passes
    its own on, then the kernel signals the foreground group) and is nobody asking for more haste;
    the watchdog still ends the stop within HARD_STOP_S. Plain ``signal.signal`` handlers run
    between any two bytecodes of the main thread, even while the event loop is busy; they only
    take lock-free steps. A signal that lands on
    another thread (Zenoh's) still wakes the loop: Python writes it to the wakeup socket."""
    loop = asyncio.get_running_loop()
    controller.watchdog = StopWatchdog(HARD_STOP_S, controller.kill_sim)
    controller._signal_wakeup = wake_loop_on_signals(loop)
    kept = ignored_signals()

    def on_signal(signum, frame):
        for sig in (signal.SIGINT, signal.SIGTERM):
            if sig not in kept:
                signal.signal(sig, signal.SIG_DFL)
        controller.watchdog.arm()
        with contextlib.suppress(RuntimeError):          # the loop has already closed
            loop.call_soon_threadsafe(controller.begin_stop, signal.Signals(signum).name)

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        if sig not in kept:
            signal.signal(sig, on_signal)


def ignored_signals() -> set[int]:
    """SIGINT and SIGHUP where they are ignored, as they stay: a shell's background job ignores
    SIGINT (a Ctrl-C at the terminal is not for it), nohup SIGHUP. The running controller caught
    them all the same, so a background job's Ctrl-C was ignored while it started and stopped it
    once it was up (an outside tester)."""
    return {sig for sig in (signal.SIGINT, signal.SIGHUP) if signal.getsignal(sig) == signal.SIG_IGN}


def wake_loop_on_signals(loop) -> tuple[socket.socket, socket.socket]:
    """Python runs a ``signal.signal`` handler on the main thread, at its next bytecode: a signal
    the kernel hands to another thread (Zenoh's, a camera's) would wait for the main thread's
    select to end. A wakeup socket the loop reads ends that select. Returns the pair, to keep open
    for the process's lifetime."""
    wake_r, wake_w = socket.socketpair()
    for sock in (wake_r, wake_w):
        sock.setblocking(False)

    def drain() -> None:
        with contextlib.suppress(OSError):
            while wake_r.recv(64):
                pass

    loop.add_reader(wake_r.fileno(), drain)
    signal.set_wakeup_fd(wake_w.fileno(), warn_on_full_buffer=False)
    return wake_r, wake_w
