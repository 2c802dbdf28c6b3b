"""The controller's way out: stop within a few wall seconds whatever the parts do, actuators
safe first (controller/app.py's ``Controller`` has it as a base class)."""
from __future__ import annotations

import asyncio
import logging
import time

from controller import shutdown
from controller.feed_outcome import reconcile

log = logging.getLogger("fishfarm")


class Stopping:
    """``stop``, ``begin_stop``, ``kill_sim`` and their helpers, over the Controller's attributes."""

    async def stop(self) -> None:
        """Stop within a few wall seconds whatever the parts do: each step has a deadline,
        and a task that ignores its cancel is left behind, not waited for (on Python 3.11 a cancel
        can be swallowed). Order: our tasks, actuators safe, devices closed, the ledger's last
        rows, the bus, the simulated devices' child, then the stop's farm time and the ledger closed."""
        self.stopping.set()
        if self.watchdog is not None:
            self.watchdog.arm()
        if self._stopped:
            return
        self._stopped = True
        began = last = time.monotonic()
        took = {}

        def step(name):
            nonlocal last
            now = time.monotonic()
            took[name], last = now - last, now

        tasks = [t for t in (self._starting, *self.tasks) if t is not None]
        if getattr(self, "survey_stops", None) is not None:   # surveys being measured are not recorded
            tasks += list(self.survey_stops.stop.finishing)
        for task in tasks:
            task.cancel()
        await shutdown.ended(tasks, shutdown.STOP_TASKS_S, "task")
        step("tasks")
        devices = [d for d in getattr(self, "devices", {}).values()
                   if getattr(d, "_opened", False) and not getattr(d, "_closed", True)]
        await self._make_safe(devices)
        settling = asyncio.ensure_future(self._settle_stopped_run())
        await shutdown.ended([settling], shutdown.SETTLE_S, "settling the stopped run")
        if self.lane is not None and not await shutdown.in_thread(self.lane.close, shutdown.CLOSE_DEVICE_S):
            log.warning("stopping: the e-stop lane did not end in %g s", shutdown.CLOSE_DEVICE_S)
        step("actuators")
        closing = [asyncio.ensure_future(d.close()) for d in devices]
        await shutdown.ended(closing, shutdown.CLOSE_DEVICE_S, "device close")
        step("devices")
        sim = asyncio.ensure_future(self.sim.stop()) if self.sim is not None else None
        if hasattr(self, "store"):
            try:
                if hasattr(self, "overrides"):
                    self.overrides.flush_audit()  # this turn's audit rows
                if hasattr(self, "alarms"):
                    self.alarms.flush()       # repeats counted since their last write
            except Exception:
                log.exception("ledger: its last rows not written")
        step("ledger")
        if hasattr(self, "bus") and not await shutdown.in_thread(self.bus.close, shutdown.CLOSE_BUS_S):
            log.warning("bus: Zenoh session did not close in %g s; leaving it", shutdown.CLOSE_BUS_S)
        step("bus")
        if sim is not None:
            await shutdown.ended([sim], shutdown.SIM_STOP_S, "simulated devices' stop")
        step("sim")
        if hasattr(self, "store"):
            self._close_ledger()
        # a start refused for bad input says so in one line (the CLI's); nothing ran to report on
        report = log.info if hasattr(self, "store") else log.debug
        report("controller stopped in %.2f s (%s)", time.monotonic() - began,
               ", ".join(f"{name} {s:.2f}" for name, s in took.items()))

    def _close_ledger(self) -> None:
        """The farm time the stop ended at, then the ledger closed: a simulated farm restarted on it
        carries on from there (its clock ran on through the stop, past the ledger's last row, and
        the next run's first lines were dated before this one's last)."""
        try:
            self.store.mark_stopped(self.clock.now())
        except Exception:  # noqa: BLE001 - an unwritable ledger is said already; the stop goes on
            log.debug("ledger: the stop's farm time not written", exc_info=True)
        finally:
            try:
                self.store.close()
            except Exception:
                log.exception("ledger: closing failed")

    def begin_stop(self, why: str) -> None:
        if not self.stopping.is_set():
            log.info("%s: stopping (a second signal ends the process at once)", why)
        self.stopping.set()

    def kill_sim(self) -> None:
        """From the watchdog's thread, just before the process ends: leave no simulator behind."""
        if self.sim is not None:
            self.sim.kill()
            self.sim.remove_dir()

    async def _settle_stopped_run(self) -> None:
        """A run the stop cut short is booked now from the dispenser's counters (the grams its load
        cell saw leave), so a clean stop leaves no intent open. An outcome less certain than "done"
        (the auger still turning, a START perhaps still on the wire) stays open for the next start."""
        if self.robot is None or not hasattr(self, "store") or not self.store.open_intents():
            return
        state = await self.robot.dispensing.read()
        waiting = {job.demand_id for job in self.robot.pending.values() if job.demand_id is not None}
        for feed in self.store.open_intents():
            result = reconcile(feed, state)
            if result.phase == "done":
                closed = self.robot.dispensing._close(result, feed.demand_id if feed.demand_id in waiting
                                                      else None, "settled on the way out")
                log.info("stopping: feed %s to %s booked at %.1f g", closed.id, closed.tank, closed.grams or 0.0)

    async def _make_safe(self, devices) -> None:
        """Auger off, refill gate closed, carriage stopped: each through its interface, each with
        its own deadline, so a device that is gone costs SAFE_COMMAND_S and no more."""
        commands = []
        for device in devices:
            if device.kind == "dispenser":
                commands += [("auger stop", device.stop()), ("refill gate close", device.set_refill(False))]
            elif device.kind == "rail":
                commands.append(("drive stop", device.stop()))
            elif device.kind == "thrusters":
                commands.append(("thrusters stop", device.stop()))
        if not commands:
            return
        tasks = {asyncio.ensure_future(cmd): what for what, cmd in commands}
        done, _ = await asyncio.wait(tasks, timeout=shutdown.SAFE_COMMAND_S)
        for task, what in tasks.items():
            if task not in done:
                task.cancel()
                log.warning("stopping: %s not confirmed in %g s", what, shutdown.SAFE_COMMAND_S)
            elif not task.cancelled() and task.exception() is not None:
                log.warning("stopping: %s failed: %s", what, task.exception())
