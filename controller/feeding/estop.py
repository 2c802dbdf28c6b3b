"""The e-stop lane: sets the devices' e-stop latches on a path nothing else can delay.

A safety relay, not a task: ``trip()`` may be called from any thread (the Zenoh thread that
received the ``estop`` query calls it before even parsing the payload). It sets the stop token
(``tripped``) first, synchronously — every actuator command of the robot checks it — sends the
first ESTOPs from the calling thread itself unless it runs an event loop (the drive's frame, then
the dispenser's exchange, then the thrusters': the caller's thread is held for about one round trip each,
``estop_timeout_s`` at worst), then wakes the lane's own thread, which

- sends the drive's ESTOP frame straight onto the bus (``RailDrive.trip_estop``) and watches for a
  status frame in "estop" (noted on the CAN reader thread, not the loop);
- writes the dispenser's ESTOP over the dispenser's e-stop connection and reads STATE back
  (``Dispenser.trip_estop``), until bit3 shows the latch;
- with a pond cleaner, writes the thrusters' latch line and reads their state back
  (``Thrusters.trip_estop``), until it shows the latch — any further ``Latch`` likewise;
- retries each every ``retry_s`` (backing off to 1 s) until it confirms, reports a device still
  unconfirmed after ``confirm_within_s`` (the robot raises the ``estop`` alarm with it) and keeps
  retrying; once all confirmed it looks again every ``recheck_s`` (a power-cycled PLC loses its
  latch). Each latch is confirmed on its own: one device that does not answer delays no other.

The event loop is never waited for: news goes to it with ``call_soon_threadsafe``. ``release()``
(an operator's reset) stops the lane before the robot resets the latches; it waits for at most
one exchange in progress (``estop_timeout_s`` of the dispenser), so no late ESTOP re-latches a
device just reset.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import math
import threading
import time
from collections.abc import Callable

from devices.errors import DeviceError

log = logging.getLogger("fishfarm.estop")

Report = Callable[[str, str | None], None]
"""``report(device, None)`` when ``device`` confirmed its latch, ``report(device, why)`` when it
has not within the bound. Called on the lane's thread: hand it on, do not block."""


def _on_a_loop() -> bool:
    try:
        asyncio.get_running_loop()
    except RuntimeError:
        return False
    return True


def log_latch(device: str, why: str | None) -> None:
    """What the lane reported of ``device``'s latch, in the log (on the loop)."""
    if why is None:
        log.warning("e-stop: %s confirmed its latch", device)
    else:
        log.error("e-stop: %s has not confirmed its latch: %s (retrying)", device, why)


class Halted(Exception):
    """An actuator command was not sent: the e-stop is tripped."""


class Latch:
    """One device's e-stop latch as the lane drives it: ``send()`` sets it (blocking, bounded; a
    ``DeviceError`` when the device cannot be reached), ``confirmed(sent_at, reply)`` says whether
    it holds, from the reply of the latest send or from what the device reported since the first
    one was sent (``sent_at``, monotonic). The default reads a state with an ``estop`` flag back
    (the dispenser's STATE, the thrusters' state)."""

    unconfirmed_why = "its state does not show the latch"

    def __init__(self, name: str, device):
        self.name, self.device = name, device

    def send(self):
        return self.device.trip_estop()

    def confirmed(self, sent_at: float, reply) -> bool:
        return bool(getattr(reply, "estop", False))

    def settle(self, sent_at: float, retry_s: float) -> None:
        """Wait briefly for a confirmation that comes on its own (nothing to wait for here)."""


class DriveLatch(Latch):
    """The rail drive: its ESTOP frame goes straight onto the bus; any status frame in "estop" seen
    after the first send confirms it (noted on the CAN reader thread, not the loop)."""

    def confirmed(self, sent_at: float, reply) -> bool:
        return self.device.estop_seen_since(sent_at)

    def settle(self, sent_at: float, retry_s: float) -> None:
        """The drive answers an accepted ESTOP with a status frame at once: wait for it briefly."""
        deadline = sent_at + retry_s
        while not self.device.estop_seen_since(sent_at) and time.monotonic() < deadline:
            time.sleep(0.0002)


class DispenserLatch(Latch):
    unconfirmed_why = "its STATE does not show the latch"


# The reason an e-stop override trips with on the Zenoh thread, before its payload is read; the
# override's own reason (its operator and why) replaces it when it follows.
PROVISIONAL = "operator e-stop"


class EstopLane:
    def __init__(self, rail, dispenser, *more: Latch, confirm_within_s: float = 0.25, retry_s: float = 0.02,
                 recheck_s: float = 1.0):
        """The feeder's two latches (the drive's, the dispenser's), then ``more`` (the cleaner's
        thrusters), each confirmed on its own; they are sent in this order."""
        self.rail, self.dispenser = rail, dispenser
        self.latches: tuple[Latch, ...] = (DriveLatch("drive", rail), DispenserLatch("dispenser", dispenser), *more)
        self.confirm_within_s, self.retry_s, self.recheck_s = confirm_within_s, retry_s, recheck_s
        self.reason: str | None = None
        self._tripped = False
        self._gen = 0                              # one per trip: a release ends its sends
        self._flag = threading.Lock()              # guards the fields above (held for no I/O)
        self._sending = threading.Lock()           # held around each exchange with a device
        self._wake = threading.Event()
        self._closed = False
        self._thread: threading.Thread | None = None
        self._confirmed: concurrent.futures.Future = concurrent.futures.Future()
        self._reports: list[Report] = []
        self.unconfirmed: dict[str, str] = {}      # device -> why its latch is not confirmed
        self._first: tuple | None = None           # (gen, {device: (sent at, reply)}) from trip()
        self._tripped_at = -math.inf               # monotonic time of the standing trip

    @property
    def DEVICES(self) -> tuple[str, ...]:        # noqa: N802 - the names the feeder's code knew
        return tuple(latch.name for latch in self.latches)

    @property
    def tripped(self) -> bool:
        """The stop token: no actuator command may be sent while it is set."""
        return self._tripped

    def replace_device(self, old, new) -> None:
        """A fresh driver takes over ``old``'s latch (its link was lost for good). A tripped lane
        is woken to latch it at once."""
        for latch in self.latches:
            if latch.device is old:
                latch.device = new               # the lane's thread reads it whole: one assignment
        if self._tripped:
            self._wake.set()

    def listen(self, report: Report) -> None:
        self._reports.append(report)

    def alarm_text(self, reason: str) -> str:
        """The ``estop`` alarm's text: the reason, and the devices not confirmed yet."""
        text = reason if reason.startswith("emergency stop") else f"emergency stop: {reason}"
        unconfirmed = sorted(dict(self.unconfirmed).items())
        if unconfirmed:
            text += "; not confirmed by " + ", ".join(f"{d} ({w})" for d, w in unconfirmed)
        return text

    def trip(self, reason: str) -> concurrent.futures.Future:
        """Stop everything now, from any thread; safe to call again. The future is done (True)
        once every device has confirmed its latch; it is never failed."""
        with self._flag:
            first = not self._tripped
            if first:
                self._tripped = True               # the token first: nothing may start from here on
                self._tripped_at = time.monotonic()
                self._gen += 1
                self.reason = reason
                if self._confirmed.done():
                    self._confirmed = concurrent.futures.Future()
            elif self.reason == PROVISIONAL and reason != PROVISIONAL:
                self.reason = reason               # the operator's own words, once their payload is read
            confirmed, gen = self._confirmed, self._gen
            if not self._closed and (self._thread is None or not self._thread.is_alive()):
                self._thread = threading.Thread(target=self._run, name="estop-lane", daemon=True)
                self._thread.start()
        if first and threading.current_thread() is not self._thread and not _on_a_loop():
            # the first ESTOPs go out from the caller's thread, now: waking the lane's thread first
            # would add a scheduling hop (and a GIL hand-over) before anything reaches a device.
            # Not from an event loop's thread: blocking I/O there would stall the loop.
            first = {}
            for latch in self.latches:
                stamp = time.monotonic()
                first[latch.name] = (stamp, self._send(gen, latch.send, {}, latch.name))
            self._first = (gen, first)            # the lane goes on from here
        self._wake.set()
        return confirmed

    def confirming(self, within_s: float) -> bool:
        """A trip younger than ``within_s`` (wall) whose latches are not all confirmed yet: a reset
        now would release stops no device has shown (its ESTOPs still in flight are cut)."""
        return (self._tripped and not self._confirmed.done()
                and time.monotonic() - self._tripped_at < within_s)

    def release(self) -> None:
        """The operator reset: stop asserting the latches. Returns once no ESTOP is in flight."""
        with self._sending, self._flag:
            self._tripped = False
            self._gen += 1
            self.reason = None
            self.unconfirmed.clear()
        self._wake.set()

    def close(self) -> None:
        with self._flag:
            self._closed = True
        self._wake.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(2.0)

    # -- the lane's thread --------------------------------------------------------------------
    def _run(self) -> None:
        while not self._closed:
            self._wake.wait(self.recheck_s if self._tripped else None)
            self._wake.clear()
            if self._closed:
                return
            if self._tripped:
                self._latch(self._gen)

    def _latch(self, gen: int) -> None:
        """Set every latch and retry until each confirms (or a release/another trip comes)."""
        started = time.monotonic()
        pending = {latch.name: latch for latch in self.latches}
        sent_at: dict[str, float] = {}             # device -> its first accepted send this trip
        first, self._first = self._first, None
        if first is not None and first[0] == gen:     # what trip() sent from its caller's thread
            for name, (stamp, reply) in first[1].items():
                if reply is not None and name in pending:
                    sent_at[name] = stamp
                    if pending[name].confirmed(stamp, reply):
                        del pending[name]
        told: set[str] = set()
        why: dict[str, str] = {}
        delay = self.retry_s
        while pending:
            replies = {}
            for name, latch in pending.items():     # (re)send each
                stamp = time.monotonic()
                replies[name] = self._send(gen, latch.send, why, name)
                if replies[name] is not None:
                    sent_at.setdefault(name, stamp)
            if gen != self._gen:
                return
            for name, latch in list(pending.items()):
                if name not in sent_at:
                    continue
                latch.settle(sent_at[name], self.retry_s)
                if latch.confirmed(sent_at[name], replies[name]):
                    del pending[name]
                elif replies[name] is not None and replies[name] is not True:
                    why[name] = latch.unconfirmed_why
            for name in self.DEVICES:
                if name not in pending and name in told:
                    told.discard(name)
                    self._tell(name, None)
            if pending and time.monotonic() - started >= self.confirm_within_s:
                for name in pending.keys() - told:
                    told.add(name)
                    self._tell(name, why.get(name, "no confirmation"))
            if pending:                   # fast at first, then backing off to once a second
                time.sleep(delay)
                if time.monotonic() - started >= self.confirm_within_s:
                    delay = min(1.0, delay * 2)
        with self._flag:
            if gen == self._gen and not self._confirmed.done():
                self._confirmed.set_result(True)

    def _send(self, gen: int, action, why: dict, device: str):
        with self._sending:
            if gen != self._gen:                  # released (or re-tripped) meanwhile: not ours
                return None
            try:
                result = action()
            except DeviceError as exc:
                why[device] = exc.text
                return None
            except Exception as exc:  # noqa: BLE001 - a driver bug must not end the lane
                log.exception("e-stop lane: %s", device)
                why[device] = f"{type(exc).__name__}: {exc}"
                return None
        return True if result is None else result

    def _tell(self, device: str, why: str | None) -> None:
        if why is None:
            self.unconfirmed.pop(device, None)
        else:
            self.unconfirmed[device] = why
        for report in self._reports:
            try:
                report(device, why)
            except Exception:  # noqa: BLE001
                log.exception("e-stop lane: report failed")
