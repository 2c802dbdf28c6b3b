"""The pond cleaner's legal moves: a ``transitions`` table, and the little it remembers.

``mission`` is what the operator (or ``autostart``) asked of it: ``"clean"`` (cover the pond),
``"return"`` (go to the dock), or None (nothing: docked and idle). States:

- docked: at the dock, thrusters stopped; ``start`` begins (or resumes) a cleaning run.
- localising: a mission, but no float fix yet: thrusters stopped until the tracker is "tracking".
- cleaning / returning: following the coverage path / the route to the dock.
- lost: the tracker lost the float: thrusters stopped; when it is back, the mission resumes
  (cleaning, or returning if ``return`` came meanwhile).
- fault: the camera or the thrusters are gone; on recovery, localise again (the robot may have
  drifted) or, with no mission, docked.
- estop: from every state. ``reset`` only once the thrusters' latch is confirmed released
  (``latch_released``, the model's), to localising (a mission stands) or docked.
- manual: the operator's ``stop``: nothing of ours moves until ``start`` or ``return``.

The machine holds no devices: the coordinator (cleaner.py) acts on the state it is in.
"""
from __future__ import annotations

import logging
from collections.abc import Callable

from transitions import Machine

log = logging.getLogger("fishfarm.cleaner")

STATES = ["docked", "localising", "cleaning", "returning", "lost", "fault", "estop", "manual"]
MOVING = ("cleaning", "returning")          # the only states in which the thrusters may be driven
HOLDING = ["docked", "localising", "cleaning", "returning", "lost", "manual"]
OPERATOR = ("start", "stop", "go_home")

TRANSITIONS = [
    # trigger           source                       dest          conditions        unless            before
    ["start",           ["docked", "manual"],        "localising", None,             None,             "_to_clean"],
    ["go_home",         "cleaning",                  "returning",  None,             None,             "_to_return"],
    ["go_home",         ["localising", "lost"],      None,         None,             None,             "_to_return"],
    ["go_home",         "manual",                    "localising", None,             None,             "_to_return"],
    ["stop",            [*HOLDING[:-1], "fault"],    "manual"],
    ["float_tracking",  ["localising", "lost"],      "cleaning",   "cleaning_asked"],
    ["float_tracking",  ["localising", "lost"],      "returning",  "has_mission",    "cleaning_asked"],
    ["float_lost",      list(MOVING),                "lost"],
    ["path_done",       "cleaning",                  "returning",  None,             None,             "_to_return"],
    ["path_done",       "returning",                 "docked",     None,             None,             "_to_rest"],
    ["device_fault",    HOLDING,                     "fault"],
    ["device_recovered", "fault",                    "localising", "has_mission"],
    ["device_recovered", "fault",                    "docked",     None,             "has_mission"],
    ["estop",           "*",                         "estop"],
    ["reset",           "estop",                     "localising", ["latch_released", "has_mission"]],
    ["reset",           "estop",                     "docked",     "latch_released", "has_mission"],
]


class CleanerMachine:
    """The model: ``state`` and ``mission``; triggers are the table's (``start()``, ``estop()``...),
    each returning True when it moved (or, for an internal one, acted). A trigger that does not
    apply in the current state returns False and changes nothing: a float seen while docked is
    no event. ``on_change(state)`` is called after every state change (publish, persist, act)."""

    def __init__(self, initial: str = "docked", mission: str | None = None, *,
                 latch_released: Callable[[], bool] = lambda: True,
                 on_change: Callable[[str], None] | None = None):
        if initial not in STATES:
            raise ValueError(f"unknown cleaner state {initial!r}")
        self.mission = mission
        self._released = latch_released
        self._on_change = on_change
        self.machine = Machine(model=self, states=STATES, transitions=TRANSITIONS, initial=initial,
                               auto_transitions=False, ignore_invalid_triggers=True,
                               after_state_change="_changed")

    # conditions
    def cleaning_asked(self) -> bool:
        return self.mission == "clean"

    def has_mission(self) -> bool:
        return self.mission is not None

    def latch_released(self) -> bool:
        return bool(self._released())

    @property
    def moving(self) -> bool:
        return self.state in MOVING

    def allows(self, trigger: str) -> bool:
        """Whether ``trigger`` has a move from here (conditions aside): operator commands ask first."""
        return bool(self.machine.get_transitions(trigger=trigger, source=self.state))

    def fire(self, trigger: str) -> bool:
        """``trigger`` if it applies here (else False, quietly: a float seen while cleaning is no news)."""
        return self.allows(trigger) and getattr(self, trigger)()

    # before-callbacks: what a move asks of the robot
    def _to_clean(self) -> None:
        self.mission = "clean"

    def _to_return(self) -> None:
        self.mission = "return"

    def _to_rest(self) -> None:
        self.mission = None

    def _changed(self) -> None:
        log.info("cleaner: %s%s", self.state, f" (mission {self.mission})" if self.mission else "")
        if self._on_change is not None:
            self._on_change(self.state)
