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


def test_contacts_waiting_to_be_read_hold_the_fast_clock_until_they_are_read():
    """At the fast speed a stuck sensor's contacts outran the controller: hundreds of farm seconds
    behind when an episode slowed the clock, its demand was raised a minute late. A read that
    leaves more than BEHIND_N contacts waiting (its rate over its span, times how far its newest
    is behind) says busy at once (the batch then holds the loop, and the pacer); the pacer holds
    it busy until a read leaves fewer. Hundreds of farm seconds of turbulence are no backlog."""
    from controller.pace import BEHIND_N, declare, mind_contacts
    c = Clock()
    now = c.now()
    ctl = NS(clock=c, cfg=cfg("20:30"), robot=robot(), hub_clock=NS(off=False))

    def read(n, first, last):          # n contacts evenly from ``first`` to ``last`` s before now
        return [NS(t=now - first + (first - last) * i / (n - 1)) for i in range(n)]

    stuck = read(401, 180.0, 100.0)                  # 5 a second, the newest 100 s behind: ~500 wait
    mind_contacts(ctl, stuck)
    assert abs(ctl.contacts_waiting - 500.0) < 1e-6 and c.said == [("busy", None, "contacts behind")]
    declare(ctl)
    assert c.said[-1] == ("busy", None, "contacts behind")
    declare(NS(clock=c, cfg=ctl.cfg, robot=robot(state="moving"), contacts_waiting=ctl.contacts_waiting))
    assert c.said[-1] == ("busy", None, "moving")                 # the robot's word first

    mind_contacts(ctl, read(51, 10.0 + 0.9 * BEHIND_N / 5, 0.9 * BEHIND_N / 5))   # then fewer than BEHIND_N
    assert 0.89 * BEHIND_N < ctl.contacts_waiting < 0.91 * BEHIND_N and len(c.said) == 3
    declare(ctl)
    assert c.said[-1] == ("idle", LOCAL_MIDNIGHT + 20.5 * 3600, "next survey")

    mind_contacts(ctl, read(10, 600.0, 290.0))       # turbulence at 60,000x: 10 contacts in 310 s, 290 s behind
    assert ctl.contacts_waiting < 10 and len(c.said) == 4
    for quiet in ([], [NS(t=now - 1e5)]):            # no rate to go by
        mind_contacts(ctl, quiet)
        assert ctl.contacts_waiting == 0.0
    ctl.hub_clock.off = True                         # a hub clock off: stamps replaced by arrival times
    mind_contacts(ctl, stuck)
    assert ctl.contacts_waiting == 0.0 and len(c.said) == 4

    plain = NS(clock=NS(now=c.now), hub_clock=NS(off=False))     # a fixed-speed clock has no word to say
    mind_contacts(plain, stuck)
    assert plain.contacts_waiting > BEHIND_N and len(c.said) == 4
