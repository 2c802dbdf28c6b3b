"""The e-stop lane: sets the devices' e-stop latches on a path nothing else can delay.

A safety relay, not a task: ``trip()`` may be called from any thread (the Zenoh thread that
received the ``estop`` query calls it before even parsing the payload). It sets the stop token
(``tripped``) first, synchronously — every actuator command of the robot checks it — sends the
first ESTOPs from the calling thread itself unless it runs an event loop (the drive's frame, then
the dispenser's exchange: the caller's thread is held for about one Modbus round trip,
``estop_timeout_s`` at worst), then wakes the lane's own thread, which

- sends the drive's ESTOP frame straight onto the bus (``RailDrive.trip_estop``) and watches for a
  status frame in "estop" (noted on the CAN reader thread, not the loop);
- writes the dispenser's ESTOP over the dispenser's e-stop connection and reads STATE back
  (``Dispenser.trip_estop``), until bit3 shows the latch;
- retries each every ``retry_s`` (backing off to 1 s) until it confirms, reports a device still
  unconfirmed after ``confirm_within_s`` (the robot raises the ``estop`` alarm with it) and keeps
  retrying; once both confirmed it looks again every ``recheck_s`` (a power-cycled PLC loses its
  latch).

The event loop is never waited for: news goes to it with ``call_soon_threadsafe``. ``release()``
(an operator's reset) stops the lane before the robot resets the latches; it waits for at most
one exchange in progress (``estop_timeout_s`` of the dispenser), so no late ESTOP re-latches a
device just reset.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import logging
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


class EstopLane:
    DEVICES = ("drive", "dispenser")

    def __init__(self, rail, dispenser, *, confirm_within_s: float = 0.25, retry_s: float = 0.02,
                 recheck_s: float = 1.0):
        self.rail, self.dispenser = rail, dispenser
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
        self._first: tuple | None = None           # (gen, drive sent at, dispenser state) from trip()

    @property
    def tripped(self) -> bool:
        """The stop token: no actuator command may be sent while it is set."""
        return self._tripped

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
        once both devices have confirmed their latches; it is never failed."""
        with self._flag:
            first = not self._tripped
            if first:
                self._tripped = True               # the token first: nothing may start from here on
                self._gen += 1
                self.reason = reason
                if self._confirmed.done():
                    self._confirmed = concurrent.futures.Future()
            confirmed, gen = self._confirmed, self._gen
            if not self._closed and (self._thread is None or not self._thread.is_alive()):
                self._thread = threading.Thread(target=self._run, name="estop-lane", daemon=True)
                self._thread.start()
        if first and threading.current_thread() is not self._thread and not _on_a_loop():
            # the first ESTOPs go out from the caller's thread, now: waking the lane's thread first
            # would add a scheduling hop (and a GIL hand-over) before anything reaches a device.
            # Not from an event loop's thread: blocking I/O there would stall the loop.
            stamp = time.monotonic()
            drive = self._send(gen, self.rail.trip_estop, {}, "drive")
            state = self._send(gen, self.dispenser.trip_estop, {}, "dispenser")
            self._first = (gen, stamp if drive else None, state)   # the lane goes on from here
        self._wake.set()
        return confirmed

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
        """Set both latches and retry until each confirms (or a release/another trip comes)."""
        started = time.monotonic()
        pending = set(self.DEVICES)
        sent_at: float | None = None
        first, self._first = self._first, None
        if first is not None and first[0] == gen:     # what trip() sent from its caller's thread
            sent_at = first[1]
            if sent_at is not None and self.rail.estop_seen_since(sent_at):
                pending.discard("drive")
            if getattr(first[2], "estop", False):
                pending.discard("dispenser")
        told: set[str] = set()
        why: dict[str, str] = {}
        delay = self.retry_s
        while pending:
            if "drive" in pending:       # (re)send: any "estop" frame after the first send confirms
                stamp = time.monotonic()
                if self._send(gen, self.rail.trip_estop, why, "drive") and sent_at is None:
                    sent_at = stamp
            if "dispenser" in pending:
                state = self._send(gen, self.dispenser.trip_estop, why, "dispenser")
                if state is not None and state.estop:
                    pending.discard("dispenser")
                elif state is not None:
                    why["dispenser"] = "its STATE does not show the latch"
            if gen != self._gen:
                return
            if "drive" in pending and sent_at is not None:
                self._await_drive(sent_at)
                if self.rail.estop_seen_since(sent_at):
                    pending.discard("drive")
            for device in self.DEVICES:
                if device not in pending and device in told:
                    told.discard(device)
                    self._tell(device, None)
            if pending and time.monotonic() - started >= self.confirm_within_s:
                for device in pending - told:
                    told.add(device)
                    self._tell(device, why.get(device, "no confirmation"))
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

    def _await_drive(self, sent_at: float) -> None:
        """The drive answers an accepted ESTOP with a status frame at once: wait for it briefly."""
        deadline = sent_at + self.retry_s
        while not self.rail.estop_seen_since(sent_at) and time.monotonic() < deadline:
            time.sleep(0.0002)

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
