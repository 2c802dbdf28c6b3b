"""Which tank the rail robot surveys next, and when.

Per tank, ``survey = {every_days, at, pairs}`` (farm.toml ``[[tanks]]``): a survey is due from
``at`` (farm local time) on the day ``every_days`` after the farm day of the tank's newest survey
in the ledger (any survey: a hand-held ``fishfarm survey --tank`` counts), and at the first ``at``
after the controller started for a tank never surveyed. An operator's ``start-survey`` asks for one now.

The robot asks ``next()`` only when no feeding demand waits (feeding comes first), so a survey
never runs during feeding. A tank is skipped while paused (an operator's pause: grading, a
treatment) or fasting (an operator's ration of 0 g today); its survey waits for the resume. A tank
whose stock events took all its fish (harvested, moved out) is skipped until fish come back. A
survey that failed (the camera) or counted too few fish to weigh its tank (none: lights off, a
fouled lens, turbid water; fewer than ``[surveys] min_weighed_fish``: most fish hidden) is tried
again ``retry_s`` later; after a second such visit in a row, at the tank's own survey hour
(``at``) each day, at least ``retry_s`` on, until a survey counts fish or an operator asks for
one: cameras that stay blind would otherwise send the robot there every ``retry_s``, day and
night, through the feeding hours the survey hours keep clear of. One survey at a time: an
unfinished one (preempted by demands) is resumed before any other is started; one whose tank is
paused (or fasting, emptied) meanwhile is put aside, its pairs kept, and goes on once it may. A captured survey
holds its tank until its record lands (its last pairs are measured after the robot has left): the
ledger dates the next survey from that record, so a slow measurement must not look like no survey.
"""
from __future__ import annotations

import logging
import math
from collections import OrderedDict

from controller.surveys.stop import SurveySession

log = logging.getLogger("fishfarm.survey")
DAY_S = 86_400.0


def due(every_days: int, at: str, last_t: float | None, now: float, utc_offset_h: float,
        since: float | None = None) -> bool:
    """A survey every ``every_days`` farm days from ``at`` local time on: due at ``now``? A tank
    never surveyed is due from the first ``at`` at or after ``since`` (the schedule's start: a
    controller started by day surveys at the tank's hour, not at once) — from today's without it."""
    return now >= due_from(every_days, at, last_t, utc_offset_h, since if since is not None or last_t is not None
                           else _local_midnight(now, utc_offset_h))


def due_from(every_days: int, at: str, last_t: float | None, utc_offset_h: float, since: float) -> float:
    """The farm time from which that survey is due: the hour ``every_days`` farm days after the day
    of ``last_t`` (an overdue day waits for no hour), or the first hour at or after ``since``."""
    hh, mm = (int(x) for x in at.split(":"))
    if last_t is None:
        return _first_at(hh * 3600 + mm * 60, since, utc_offset_h)
    return (_day(last_t, utc_offset_h) + every_days) * DAY_S + hh * 3600 + mm * 60 - utc_offset_h * 3600.0


def _local_midnight(t: float, utc_offset_h: float) -> float:
    return _day(t, utc_offset_h) * DAY_S - utc_offset_h * 3600.0


def _first_at(at_s: float, t: float, utc_offset_h: float) -> float:
    """The first instant at or after ``t`` whose local time of day is ``at_s``."""
    day, time_of_day = divmod(t + utc_offset_h * 3600.0, DAY_S)
    return (day + (time_of_day > at_s)) * DAY_S + at_s - utc_offset_h * 3600.0


def _day(t: float, utc_offset_h: float) -> float:
    return math.floor((t + utc_offset_h * 3600.0) / DAY_S)


class SurveySchedule:
    def __init__(self, cfg, store, rations, clock):
        self.cfg, self.store, self.rations, self.clock = cfg, store, rations, clock
        self.current: SurveySession | None = None
        self.asked: OrderedDict[str, SurveySession] = OrderedDict()    # operators' requests, in order
        self.not_before: dict[str, float] = {}                          # tank -> retry after a failure
        self.misses: dict[str, int] = {}            # tank -> visits in a row that failed or weighed nothing
        self.recording: dict[str, SurveySession] = {}                   # tank -> captured, not yet recorded
        self.started = clock.now()            # a tank never surveyed waits for its first hour after it
        known = {t.id for t in cfg.tanks}
        for tank, t, pairs in store.surveys_asked():           # asked before a restart: asked still
            if tank in known:
                self.asked[tank] = SurveySession(tank, pairs, "operator", t)
                log.warning("survey of %s asked for before the restart: asked again (pairs captured then are "
                            "not kept)", tank)
            else:
                store.survey_answered(tank)

    def request(self, tank: str, pairs: int | None = None) -> str | None:
        """An operator's survey of ``tank`` now (after any demand waiting). A note when one is
        already asked for or running."""
        if self.current is not None and self.current.tank == tank:
            return f"a survey of {tank} is under way ({self.current.captured} of {self.current.pairs} pairs)"
        if tank in self.asked:
            return f"a survey of {tank} is asked for already"
        self.asked[tank] = session = SurveySession(tank, pairs or self.cfg.surveys.pairs, "operator", self.clock.now())
        self.store.ask_survey(tank, session.t, session.pairs)
        self.not_before.pop(tank, None)
        self.misses.pop(tank, None)
        return None

    def held(self, tank: str, paused: set[str], now: float) -> str | None:
        """Why ``tank`` is not surveyed now, or None."""
        if tank in paused:
            return "paused"
        if self.rations.stock(tank) <= 0:       # harvested or moved out: a visit would count nothing
            return "no fish"
        ration = self.rations.today(tank, now)
        if ration.source == "operator" and ration.grams == 0:
            return "fasting"
        if tank in self.recording:
            return "measuring"
        if now < self.not_before.get(tank, -math.inf):
            return "retry later"
        return None

    def next(self, paused: set[str], now: float) -> SurveySession | None:
        """The survey the robot should work on now, or None."""
        if self.current is not None:
            why = self.held(self.current.tank, paused, now)
            if why is None:
                return self.current
            # put aside, its pairs kept, until its tank may be surveyed: a grading pause of the tank
            # under way held every other tank's survey, scheduled ones too, for as long as it lasted
            log.info("survey of %s put aside (%s, %d of %d pairs): it goes on once it may", self.current.tank,
                     why, self.current.captured, self.current.pairs)
            self.asked[self.current.tank] = self.current
            self.current = None
        for tank, session in self.asked.items():
            if self.held(tank, paused, now) is None:
                self.current = self.asked.pop(tank)
                return session
        for tank in self.cfg.tanks:
            plan = tank.survey
            if plan is None or self.held(tank.id, paused, now) is not None:
                continue
            newest = self.store.surveys(tank.id, until=now, limit=1)
            if due(plan.every_days, plan.at, newest[0].t if newest else None, now, self.cfg.utc_offset_h,
                   since=self.started):
                self.current = SurveySession(tank.id, plan.pairs, "schedule", now)
                return self.current
        return None

    def ended(self, session: SurveySession, outcome: str, now: float) -> None:
        """A visit's outcome: ``captured`` ends the session (its record follows), ``failed`` drops it
        until ``retry_s`` has passed, ``preempted`` keeps it for the next visit."""
        if outcome == "preempted":
            return
        if self.current is session:
            self.current = None
        if outcome == "captured":
            self.recording[session.tank] = session
        else:
            if session.why == "operator":
                # asked for by an operator: tried again as a scheduled one is (it was dropped, though
                # the log said "tried again"), its pairs kept
                session.failed = session.unfit = None
                self.asked[session.tank] = session
            self._missed(session.tank, now, "failed")

    def recorded(self, session: SurveySession, now: float) -> None:
        """A captured survey's record has landed in the ledger (or failed to): its tank may be
        surveyed again once the ledger says it is due."""
        if self.recording.get(session.tank) is session:
            del self.recording[session.tank]
        self._answered(session)
        if self.store.surveys(session.tank, since=session.t, limit=1):
            self.misses.pop(session.tank, None)
            # the ledger dates the next survey from this one
            self.not_before[session.tank] = now + self.cfg.surveys.retry_s
        else:
            self._missed(session.tank, now, f"counted fewer than {self.store.min_weighed} fish")

    def _answered(self, session: SurveySession) -> None:
        if session.why == "operator" and session.tank not in self.asked:    # not asked anew meanwhile
            self.store.survey_answered(session.tank)

    def _missed(self, tank: str, now: float, what: str) -> None:
        """A visit that failed or counted too few fish: the tank's next try (module docstring)."""
        misses = self.misses[tank] = self.misses.get(tank, 0) + 1
        retry = now + self.cfg.surveys.retry_s
        plan = self.cfg.tank(tank).survey
        if misses >= 2 and plan is not None:
            hh, mm = (int(x) for x in plan.at.split(":"))
            retry = _first_at(hh * 3600 + mm * 60, retry, self.cfg.utc_offset_h)
        self.not_before[tank] = retry
        wait = retry - now
        log.warning("survey of %s %s (%d in a row): tried again in %s", tank, what, misses,
                    f"{wait / 3600.0:.1f} h" if wait >= 3600.0 else f"{wait / 60.0:.0f} min")
