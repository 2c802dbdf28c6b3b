"""The e-stop lane with the cleaner's thrusters as a third latch: one trip latches the drive, the
dispenser and the thrusters; each is confirmed on its own, so a device that does not answer is
reported by name and delays no other."""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from controller.feeding.estop import EstopLane, Latch
from devices.errors import LinkDown


@dataclass(frozen=True)
class State:
    estop: bool


class LatchingDevice:
    """A device holding its own latch; ``deaf`` ones are unreachable, ``numb`` ones answer without it."""

    def __init__(self, name, *, deaf=False, numb=False):
        self.name, self.deaf, self.numb = name, deaf, numb
        self.latched = False
        self.calls = 0
        self.threads = []

    def trip_estop(self):
        self.calls += 1
        self.threads.append(threading.current_thread())
        if self.deaf:
            raise LinkDown(self.name, "no answer on the line")
        self.latched = not self.numb
        return State(self.latched)

    def estop_seen_since(self, t):          # as a rail drive
        return self.latched


def wait_for(cond, s=2.0):
    deadline = time.monotonic() + s
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.002)
    return cond()


def test_one_trip_latches_all_three_from_the_callers_thread():
    rail, dispenser, thrusters = LatchingDevice("rail"), LatchingDevice("dispenser"), LatchingDevice("thrusters")
    lane = EstopLane(rail, dispenser, Latch("thrusters", thrusters))
    assert lane.DEVICES == ("drive", "dispenser", "thrusters")
    result = []
    caller = threading.Thread(target=lambda: result.append(lane.trip("zenoh")))
    caller.start()
    caller.join(5)
    assert thrusters.threads[:1] == [caller] and rail.threads[:1] == [caller]
    assert result[0].result(timeout=2.0) is True
    assert rail.latched and dispenser.latched and thrusters.latched
    lane.close()


def test_unreachable_thrusters_are_named_and_delay_neither_feeder_latch():
    reports = []
    rail, dispenser, thrusters = LatchingDevice("rail"), LatchingDevice("dispenser"), LatchingDevice("t", deaf=True)
    lane = EstopLane(rail, dispenser, Latch("thrusters", thrusters), confirm_within_s=0.05, retry_s=0.005)
    lane.listen(lambda device, why: reports.append((device, why)))
    done = lane.trip("test")
    assert wait_for(lambda: reports)
    assert reports == [("thrusters", "no answer on the line")] and not done.done()
    assert rail.latched and dispenser.latched
    assert "not confirmed by thrusters (no answer on the line)" in lane.alarm_text("test")
    calls = thrusters.calls
    assert wait_for(lambda: thrusters.calls > calls)             # it keeps trying the thrusters
    thrusters.deaf = False                                       # back on the line: confirmed
    assert done.result(timeout=3.0) is True and thrusters.latched
    assert wait_for(lambda: ("thrusters", None) in reports) and lane.unconfirmed == {}
    lane.release()
    calls = thrusters.calls
    time.sleep(0.05)
    assert thrusters.calls == calls                              # released: no more sends
    lane.close()


def test_a_state_without_the_latch_is_not_a_confirmation():
    reports = []
    thrusters = LatchingDevice("t", numb=True)
    lane = EstopLane(LatchingDevice("rail"), LatchingDevice("dispenser"), Latch("thrusters", thrusters),
                     confirm_within_s=0.02, retry_s=0.005)
    lane.listen(lambda device, why: reports.append((device, why)))
    done = lane.trip("test")
    assert wait_for(lambda: reports)
    assert reports == [("thrusters", "its state does not show the latch")] and not done.done()
    lane.release()
    lane.close()
