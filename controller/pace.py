"""The controller's word to an elastic farm clock (devices/elastic_clock.py).

Busy (the slow speed) while the robot is anything but idle (homing, moving, dispensing,
refilling, surveying, a fault, an e-stop) or a demand waits or a survey is under way; otherwise
idle until the next scheduled survey hour of any tank, whose clock then slows by itself at that
hour. Each hour stays slow for ``GRACE_S`` after it, so the idle robot, which looks for due
surveys every 30 farm s, has found it before the clock may speed on. Other periodic work
(housekeeping, thermometer reads) keeps no fine time when nothing happens and needs no word.
A survey stop runs at a tenth of the slow speed: its wall time is rendering and measuring, so a
slower clock costs no wall and keeps the survey to a real one's farm minutes.
"""
from __future__ import annotations

import asyncio

from controller.surveys.schedule import _first_at

GRACE_S = 60.0           # farm s a survey hour stays slow
SURVEY_SHARE = 0.1       # a survey stop at this share of the slow speed (below)
PERIOD_S = 0.005         # wall s between looks: bounds how soon the clock speeds up, not when it slows


def next_survey_hour(cfg, now: float) -> float | None:
    """The first tank survey hour at or after ``now - GRACE_S`` (any tank's, due or not)."""
    hours = []
    for tank in cfg.tanks:
        if tank.survey is not None:
            hh, mm = (int(x) for x in tank.survey.at.split(":"))
            hours.append(_first_at(hh * 3600 + mm * 60, now - GRACE_S, cfg.utc_offset_h))
    return min(hours, default=None)


def busy_with(robot) -> str | None:
    """What keeps the robot from idling (for the clock file's record), or None."""
    if robot is None:
        return "starting"
    if robot.state != "idle":
        return robot.state
    if robot.pending:
        return "demand waiting"
    stops = robot.surveys
    if stops is not None and (stops.schedule.current is not None or stops.schedule.asked):
        return "survey due"
    if stops is not None and stops.stop.finishing:
        return "survey measuring"     # the last pairs, robot free: on a fast clock the record would
    return None                       # land hours late and the schedule start the survey again


def declare(controller) -> None:
    clock = controller.clock
    why = busy_with(getattr(controller, "robot", None))
    if why in ("surveying", "survey measuring"):
        # a survey's wall time is its rendering and measuring, whatever the clock: at the slow
        # speed 40 pairs spanned 4-5 farm hours (into the fish's morning under load); at a tenth
        # they span tens of farm minutes, as a real survey does, for the same wall
        clock.busy(max_speed=clock.slow * SURVEY_SHARE, why=why)
    elif why is not None:
        clock.busy(why=why)
    else:
        now = clock.now()
        hour = next_survey_hour(controller.cfg, now)
        clock.idle_until(now + 365 * 86400.0 if hour is None else hour, why="next survey")


async def pace(controller, period_s: float = PERIOD_S) -> None:
    while True:
        declare(controller)
        await asyncio.sleep(period_s)
