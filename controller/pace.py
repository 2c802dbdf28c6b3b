"""The controller's word to an elastic farm clock (devices/elastic_clock.py).

Busy (the slow speed) while the robot is anything but idle (homing, moving, dispensing,
refilling, surveying, a fault, an e-stop) or a demand waits or a survey is under way; otherwise
idle until the next survey hour of any tank whose survey falls due then (a weekly survey's hour
on its other six days needs no slow minute); the clock then slows by itself at that hour. Each
hour stays slow for ``GRACE_S`` after it, so the idle robot, which looks for due surveys every 30
farm s, has found it before the clock may speed on. Other periodic work
(housekeeping, thermometer reads) keeps no fine time when nothing happens and needs no word.
A survey stop runs at a tenth of the slow speed: its wall time is rendering and measuring, so a
slower clock costs no wall and keeps the survey to a real one's farm minutes.

Busy too while contacts wait to be read (``mind_contacts``, at each read, at once: a batch's
processing holds the loop, and the pacer with it): at the fast speed a stuck sensor's 5 contacts
a farm second are 36,000 a wall second, more than the controller reads (~15,000), and it fell
hundreds of farm seconds behind. When the clock slowed for the next episode, that episode's first
contacts queued behind the backlog and its demand was raised 20-230 farm s after them (feeds
62-77 s late, a farm-day test in ten failing). The fast clock now waits for the controller. What
waits is counted in contacts, not farm seconds: at 60,000x the normal lag is hundreds of farm
seconds with a handful of contacts in them, and a backlog costs its contacts' reading time.
"""
from __future__ import annotations

import asyncio
import math
import time

from controller.surveys.schedule import _first_at, due_from

GRACE_S = 60.0           # farm s a survey hour stays slow
SURVEY_SHARE = 0.1       # a survey stop at this share of the slow speed (below)
BEHIND_N = 100.0         # contacts estimated waiting past a read (~5 ms of the controller's reading:
                         # 2 farm s at the slow speed, within an episode's lead)
PERIOD_S = 0.005         # wall s between looks: bounds how soon the clock speeds up, not when it slows
NEWEST_S = 1.0           # wall s a tank's newest survey time is kept before the ledger is asked again


def next_survey_hour(cfg, now: float, newest=None, since: float | None = None) -> float | None:
    """The first tank survey hour at or after ``now - GRACE_S``: any tank's; with ``newest`` (tank
    id -> farm time of its newest survey, None if never) only hours on which the tank's survey is
    due (a weekly survey's other six days need no slow minute), ``since`` the schedule's start."""
    hours = []
    for tank in cfg.tanks:
        if tank.survey is not None:
            hh, mm = (int(x) for x in tank.survey.at.split(":"))
            hour = _first_at(hh * 3600 + mm * 60, now - GRACE_S, cfg.utc_offset_h)
            if newest is not None:
                hour = max(hour, due_from(tank.survey.every_days, tank.survey.at, newest(tank.id),
                                          cfg.utc_offset_h, since))
            hours.append(hour)
    return min(hours, default=None)


class NewestSurveys:
    """Each tank's newest survey time from the ledger, asked again once the survey stop records one
    or ``NEWEST_S`` of wall have passed (a survey another process recorded): not 200 times a second."""

    def __init__(self, stops):
        self.stops, self.known, self.asked_at, self.recorded = stops, {}, -math.inf, -1

    def __call__(self, tank: str) -> float | None:
        now = time.monotonic()
        if len(self.stops.stop.recorded) != self.recorded or now - self.asked_at > NEWEST_S:
            self.known, self.asked_at, self.recorded = {}, now, len(self.stops.stop.recorded)
        if tank not in self.known:
            rows = self.stops.schedule.store.surveys(tank, limit=1)
            self.known[tank] = rows[0].t if rows else None
        return self.known[tank]


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


def mind_contacts(controller, batch) -> None:
    """After a read: the contacts estimated still waiting (``contacts_waiting``: the batch's rate
    over its span times how far its newest stamp is behind the clock); past ``BEHIND_N``, busy at
    once, before the batch is counted. A hub clock found off waits for nothing (its stamps are
    replaced by arrival times); nor does a read of fewer than two contacts (no rate to go by)."""
    waiting = 0.0
    if len(batch) >= 2 and not controller.hub_clock.off:
        clock, first, last = controller.clock, batch[0].t, batch[-1].t
        waiting = max(0.0, (len(batch) - 1) / max(last - first, 1e-3) * (clock.now() - last))
        if waiting > BEHIND_N and hasattr(clock, "busy"):
            clock.busy(why="contacts behind")
    controller.contacts_waiting = waiting


def declare(controller, newest=None) -> None:
    clock = controller.clock
    robot = getattr(controller, "robot", None)
    why = busy_with(robot)
    if why is None and getattr(controller, "contacts_waiting", 0.0) > BEHIND_N:
        why = "contacts behind"
    if why in ("surveying", "survey measuring"):
        # a survey's wall time is its rendering and measuring, whatever the clock: at the slow
        # speed 40 pairs spanned 4-5 farm hours (into the fish's morning under load); at a tenth
        # they span tens of farm minutes, as a real survey does, for the same wall
        clock.busy(max_speed=clock.slow * SURVEY_SHARE, why=why)
    elif why is not None:
        clock.busy(why=why)
    else:
        now = clock.now()
        stops = getattr(robot, "surveys", None)
        since = stops.schedule.started if newest is not None and stops is not None else None
        hour = next_survey_hour(controller.cfg, now, newest if since is not None else None, since)
        clock.idle_until(now + 365 * 86400.0 if hour is None else hour, why="next survey")


async def pace(controller, period_s: float = PERIOD_S) -> None:
    newest = None
    while True:
        stops = getattr(getattr(controller, "robot", None), "surveys", None)
        if newest is None and stops is not None:
            newest = NewestSurveys(stops)
        declare(controller, newest)
        await asyncio.sleep(period_s)
