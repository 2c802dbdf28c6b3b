"""The controller's word to an elastic clock: busy while the robot works or anything waits for it,
else idle until the next survey hour (which stays slow a minute after it)."""
from __future__ import annotations

from types import SimpleNamespace as NS

from controller.pace import GRACE_S, busy_with, next_survey_hour

LOCAL_MIDNIGHT = 1_780_009_200.0          # 2026-05-29 00:00 local = 2026-05-28 23:00 UTC at utc_offset_h = 1


def cfg(*hours):
    return NS(utc_offset_h=1.0, tanks=[NS(survey=None)] + [NS(survey=NS(at=h)) for h in hours])


def robot(state="idle", pending=(), current=None, asked=(), finishing=()):
    return NS(state=state, pending=dict.fromkeys(pending),
              surveys=NS(schedule=NS(current=current, asked=list(asked)), stop=NS(finishing=set(finishing))))


def test_the_next_survey_hour_is_the_earliest_tank_hour_ahead():
    c = cfg("20:30", "03:30")
    at_noon = LOCAL_MIDNIGHT + 12 * 3600
    assert next_survey_hour(c, at_noon) == LOCAL_MIDNIGHT + 20.5 * 3600
    at_23h = LOCAL_MIDNIGHT + 23 * 3600
    assert next_survey_hour(c, at_23h) == LOCAL_MIDNIGHT + 27.5 * 3600      # tomorrow's 03:30
    just_after = LOCAL_MIDNIGHT + 20.5 * 3600 + GRACE_S / 2                # still slow: the robot looks
    assert next_survey_hour(c, just_after) == LOCAL_MIDNIGHT + 20.5 * 3600
    assert next_survey_hour(cfg(), at_noon) is None


def test_the_robot_idles_only_with_nothing_waiting():
    assert busy_with(None) == "starting"
    assert busy_with(robot()) is None
    assert busy_with(robot(state="moving")) == "moving"
    assert busy_with(robot(pending=["T1"])) == "demand waiting"
    assert busy_with(robot(current=object())) == "survey due"       # a preempted survey resumes
    assert busy_with(robot(asked=["T2"])) == "survey due"
    assert busy_with(robot(finishing=["a record task"])) == "survey measuring"
    assert busy_with(NS(state="idle", pending={}, surveys=None)) is None


class Clock:
    slow = 600.0

    def __init__(self):
        self.said = []

    def now(self):
        return LOCAL_MIDNIGHT + 12 * 3600

    def busy(self, max_speed=None, why=""):
        self.said.append(("busy", max_speed, why))

    def idle_until(self, t, why=""):
        self.said.append(("idle", t, why))


def test_a_survey_stop_runs_at_a_tenth_of_the_slow_speed_and_the_rest_as_busy_or_idle():
    from controller.pace import SURVEY_SHARE, declare
    c = Clock()
    declare(NS(clock=c, cfg=cfg("20:30"), robot=robot(state="surveying", current=object())))
    declare(NS(clock=c, cfg=cfg("20:30"), robot=robot(finishing=["a record task"])))
    declare(NS(clock=c, cfg=cfg("20:30"), robot=robot(state="moving")))
    declare(NS(clock=c, cfg=cfg("20:30"), robot=robot()))
    assert c.said == [("busy", 600.0 * SURVEY_SHARE, "surveying"), ("busy", 600.0 * SURVEY_SHARE, "survey measuring"),
                      ("busy", None, "moving"),
                      ("idle", LOCAL_MIDNIGHT + 20.5 * 3600, "next survey")]


def test_with_the_ledger_s_newest_surveys_only_the_hours_a_survey_falls_due_slow_the_clock():
    c = NS(utc_offset_h=1.0, tanks=[NS(id="T1", survey=NS(at="20:30", every_days=7)),
                                    NS(id="T2", survey=NS(at="03:30", every_days=7))])
    at_noon = LOCAL_MIDNIGHT + 12 * 3600
    newest = {"T1": LOCAL_MIDNIGHT - 2 * 86400 + 20.6 * 3600,     # two days ago: due in five days
              "T2": None}                                            # never: from its first hour after the start
    hour = next_survey_hour(c, at_noon, newest.get, since=at_noon - 3600)
    assert hour == LOCAL_MIDNIGHT + 27.5 * 3600                      # T2 tonight; T1's 20:30 passes fast
    newest["T2"] = LOCAL_MIDNIGHT - 86400 + 3.6 * 3600                # T2 surveyed yesterday too
    assert next_survey_hour(c, at_noon, newest.get, since=at_noon - 3600) == LOCAL_MIDNIGHT + (5 * 24 + 20.5) * 3600
    newest["T1"] = LOCAL_MIDNIGHT - 9 * 86400                        # overdue: every hour of it, as before
    assert next_survey_hour(c, at_noon, newest.get, since=at_noon - 3600) == LOCAL_MIDNIGHT + 20.5 * 3600
