"""The cleaner's state machine, checked move by move against the rules as the issue and the plan
word them (written out here, not read from the table): every trigger from every state, with and
without a mission, e-stop from each state, and a lost float resuming what the robot was doing."""
from __future__ import annotations

import itertools

import pytest

from controller.cleaning.machine import STATES, CleanerMachine

ALL = ["docked", "localising", "cleaning", "returning", "lost", "fault", "estop", "manual"]
TRIGGERS = ["start", "stop", "go_home", "float_tracking", "float_lost", "path_done", "device_fault",
            "device_recovered", "estop", "reset"]
MISSIONS = [None, "clean", "return"]


def expected(state: str, mission: str | None, trigger: str, released: bool) -> tuple[str, str | None] | None:
    """(state, mission) after ``trigger``, by the rules in words; None: the trigger does not apply."""
    after = {
        # operator: start from the dock or from hands-on, to a cleaning run (localise first)
        "start": {"docked": ("localising", "clean"), "manual": ("localising", "clean")},
        # operator: return to the dock; at once if tracking, else after re-acquiring the float
        "go_home": {"cleaning": ("returning", "return"), "localising": ("localising", "return"),
                    "lost": ("lost", "return"), "manual": ("localising", "return")},
        # operator: stop where it is (anything but an e-stop, or manual already)
        "stop": {s: ("manual", mission) for s in ("docked", "localising", "cleaning", "returning", "lost", "fault")},
        "float_lost": {"cleaning": ("lost", mission), "returning": ("lost", mission)},
        "path_done": {"cleaning": ("returning", "return"), "returning": ("docked", None)},
        "device_fault": {s: ("fault", mission) for s in ("docked", "localising", "cleaning", "returning", "lost",
                                                         "manual")},
        "device_recovered": {"fault": ("localising" if mission else "docked", mission)},
        "estop": {s: ("estop", mission) for s in ALL},
    }
    if trigger == "float_tracking" and state in ("localising", "lost") and mission is not None:
        return ("cleaning" if mission == "clean" else "returning"), mission
    if trigger == "reset" and state == "estop" and released:
        return ("localising" if mission else "docked"), mission
    return after.get(trigger, {}).get(state)


def test_the_states_are_the_issues_eight():
    assert sorted(STATES) == sorted(ALL)


@pytest.mark.parametrize("released", [True, False])
@pytest.mark.parametrize("state,mission,trigger", list(itertools.product(ALL, MISSIONS, TRIGGERS)))
def test_every_trigger_from_every_state(state, mission, trigger, released):
    changes = []
    m = CleanerMachine(state, mission, latch_released=lambda: released, on_change=changes.append)
    want = expected(state, mission, trigger, released)
    acted = getattr(m, trigger)()
    assert (m.state, m.mission) == (want or (state, mission))
    # a trigger that applies says so and tells the coordinator; one that does not changes nothing
    assert acted == (want is not None)
    assert changes == ([m.state] if want is not None else [])


@pytest.mark.parametrize("state", ALL)
def test_estop_from_every_state_and_reset_only_once_the_latch_is_released(state):
    released = [False]
    m = CleanerMachine(state, "clean" if state in ("localising", "cleaning", "lost") else None,
                       latch_released=lambda: released[0])
    assert m.estop() and m.state == "estop"
    for trigger in ("start", "go_home", "float_tracking", "path_done", "device_recovered", "stop"):
        getattr(m, trigger)()
        assert m.state == "estop", trigger          # nothing but a reset leaves it
    assert not m.reset() and m.state == "estop"     # the latch is still held
    released[0] = True
    assert m.reset() and m.state == ("localising" if m.mission else "docked")


@pytest.mark.parametrize("doing", ["cleaning", "returning"])
def test_a_lost_float_stops_then_resumes_what_it_was_doing(doing):
    m = CleanerMachine("docked")
    m.start()
    m.float_tracking()
    if doing == "returning":
        m.go_home()
    assert m.state == doing and m.moving
    assert m.float_lost() and m.state == "lost" and not m.moving
    assert not m.float_lost() and m.state == "lost"
    assert m.float_tracking() and m.state == doing


def test_return_asked_while_lost_resumes_as_returning_and_a_run_ends_docked():
    m = CleanerMachine("cleaning", "clean")
    m.float_lost()
    m.go_home()
    assert m.state == "lost" and m.mission == "return"
    m.float_tracking()
    assert m.state == "returning"
    m.path_done()
    assert (m.state, m.mission) == ("docked", None)


def test_allows_tells_operator_commands_apart_from_sensor_events():
    m = CleanerMachine("docked")
    assert m.allows("start") and not m.allows("go_home") and m.allows("stop") and m.allows("estop")
    with pytest.raises(ValueError):
        CleanerMachine("parked")
