"""When a tank's survey is due, which tanks are held back, and the start-survey override."""
from __future__ import annotations

import asyncio
from datetime import UTC, datetime

import pytest

from controller.config import Config, SurveySchedule, SurveysConfig, TankConfig
from controller.feeding.rations import Rations, load_species
from controller.overrides import Overrides
from controller.store import Store
from controller.surveys.schedule import SurveySchedule as Schedule
from controller.surveys.schedule import due
from controller.surveys.wiring import SurveyStops, survey_camera_name
from devices.clock import ManualClock
from devices.errors import BadInput
from tests.controller.override_rig import Farm

DAY = 86_400.0


def t(iso: str) -> float:
    return datetime.fromisoformat(iso).replace(tzinfo=UTC).timestamp()


@pytest.mark.parametrize("last, now, offset_h, expected", [
    (None, "2026-06-01T09:59", 0, False),                 # never surveyed: the first 10:00
    (None, "2026-06-01T10:00", 0, True),
    ("2026-06-01T10:30", "2026-06-07T23:00", 0, False),   # day 6 of 7
    ("2026-06-01T10:30", "2026-06-08T09:00", 0, False),   # day 7, before the hour
    ("2026-06-01T10:30", "2026-06-08T10:00", 0, True),    # day 7 at the hour
    ("2026-06-01T10:30", "2026-06-09T03:00", 0, True),    # overdue: no hour to wait for
    ("2026-06-01T10:30", "2026-06-08T09:00", 1, True),    # 10:00 local at UTC+1
    ("2026-06-01T23:30", "2026-06-08T09:30", 1, False),   # local 02-06 00:30: day 6 of 7 locally
])
def test_a_survey_is_due_every_n_farm_days_from_its_hour(last, now, offset_h, expected):
    assert due(7, "10:00", None if last is None else t(last), t(now), offset_h) is expected


@pytest.mark.parametrize("since, now, offset_h, expected", [
    ("2026-06-01T09:00", "2026-06-01T09:59", 0, False),   # started before the hour: that day's
    ("2026-06-01T09:00", "2026-06-01T10:00", 0, True),
    ("2026-06-01T10:00", "2026-06-01T10:00", 0, True),    # started at the hour
    ("2026-06-01T11:00", "2026-06-01T12:00", 0, False),   # started after it: the next day's, not at once
    ("2026-06-01T11:00", "2026-06-02T09:59", 0, False),
    ("2026-06-01T11:00", "2026-06-02T10:00", 0, True),
    ("2026-06-01T08:30", "2026-06-01T09:00", 1, True),    # 10:00 local at UTC+1 is 09:00 UTC
    ("2026-06-01T09:30", "2026-06-02T08:59", 1, False),
    ("2026-06-01T23:30", "2026-06-02T09:00", 1, True),    # started 00:30 local: that day's 10:00
])
def test_a_tank_never_surveyed_waits_for_its_first_hour_after_the_start(since, now, offset_h, expected):
    assert due(7, "10:00", None, t(now), offset_h, since=t(since)) is expected


def config(**surveys):
    tanks = [TankConfig(id="T1", stock=1000, mean_weight_g=20, position_m=3, sensors=["a"],
                        survey=SurveySchedule(every_days=7, at="10:00", pairs=12)),
             TankConfig(id="T2", stock=1000, mean_weight_g=20, position_m=6, sensors=["b"],
                        survey=SurveySchedule(every_days=1, at="11:00", pairs=5)),
             TankConfig(id="T3", stock=1000, mean_weight_g=20, position_m=9, sensors=["c"])]
    return Config(tanks=tanks, surveys=SurveysConfig(**surveys), path="<test>",
                  devices={"stereo": {"kind": "stereo_camera", "driver": "sim"}})


@pytest.fixture
def parts(tmp_path):
    cfg = config()
    store = Store(tmp_path / "ledger.db")
    clock = ManualClock(t=t("2026-06-01T09:00"))
    yield cfg, store, Rations(cfg, load_species(), store), clock
    store.close()


def test_tanks_come_due_at_their_hours_and_a_recorded_survey_resets_the_count(parts):
    cfg, store, rations, clock = parts
    schedule = Schedule(cfg, store, rations, clock)
    assert schedule.next(set(), clock.now()) is None
    clock.t = t("2026-06-01T10:05")
    first = schedule.next(set(), clock.now())
    assert (first.tank, first.pairs, first.why) == ("T1", 12, "schedule")
    assert schedule.next(set(), clock.now()) is first                 # resumed before anything else
    schedule.ended(first, "captured", clock.now())
    store.add_survey("T1", clock.now(), "sparus_aurata", "test", [10.0, 11.0], [25.0, 30.0])
    schedule.recorded(first, clock.now())
    clock.t = t("2026-06-01T11:00")
    assert schedule.next(set(), clock.now()).tank == "T2"             # T1 done for a week; T3 has none
    second = schedule.current
    schedule.ended(second, "captured", clock.now())
    store.add_survey("T2", clock.now(), "sparus_aurata", "test", [10.0], [25.0])
    schedule.recorded(second, clock.now())
    clock.t = t("2026-06-02T11:00")
    assert schedule.next(set(), clock.now()).tank == "T2"             # daily


def test_paused_fasting_and_failed_tanks_are_skipped_until_they_may_be_surveyed(parts):
    cfg, store, rations, clock = parts
    schedule = Schedule(cfg, store, rations, clock)
    clock.t = t("2026-06-01T12:00")
    rations.set("T2", clock.now(), 0.0, "operator")                    # a fasting day
    assert schedule.held("T2", set(), clock.now()) == "fasting"
    assert schedule.next({"T1"}, clock.now()) is None                  # T1 paused, T2 fasting
    session = schedule.next(set(), clock.now())
    assert session.tank == "T1"
    schedule.ended(session, "failed", clock.now())                     # the camera failed
    assert schedule.next(set(), clock.now()) is None
    clock.t += cfg.surveys.retry_s
    assert schedule.next(set(), clock.now()).tank == "T1"


def test_a_tank_with_no_fish_left_is_skipped_until_fish_come_back(parts):
    cfg, store, rations, clock = parts
    schedule = Schedule(cfg, store, rations, clock)
    clock.t = t("2026-06-01T12:00")
    store.add_stock_event(t=clock.now(), tank="T1", kind="harvest", count=1000, to_tank=None, who="ana")
    rations.restocked("T1", clock.now())
    assert schedule.held("T1", set(), clock.now()) == "no fish"
    assert schedule.next(set(), clock.now()).tank == "T2"             # T1 due, but empty
    schedule.current = None
    store.add_stock_event(t=clock.now(), tank="T3", kind="transfer", count=10, to_tank="T1", who="ana")
    rations.restocked("T1", clock.now())
    assert schedule.held("T1", set(), clock.now()) is None
    assert schedule.next(set(), clock.now()).tank == "T1"


@pytest.mark.parametrize("measuring_s", [0.0, 1.0, 3.0])   # x retry_s: the record lands that long after the visit
def test_a_captured_survey_is_not_started_again_while_its_record_is_pending(parts, measuring_s):
    cfg, store, rations, clock = parts
    schedule = Schedule(cfg, store, rations, clock)
    clock.t = t("2026-06-01T11:00")
    session = schedule.next(set(), clock.now())
    assert session.tank == "T1"
    schedule.ended(session, "captured", clock.now())
    step = cfg.surveys.retry_s / 4
    for _ in range(int(measuring_s * 4)):                  # the last pairs are still being measured
        clock.t += step
        assert schedule.held("T1", set(), clock.now()) == "measuring"
        assert schedule.next(set(), clock.now()).tank == "T2"
        schedule.current = None                              # T2 is not what this test is about
    store.add_survey("T1", clock.now(), "sparus_aurata", "test", [10.0], [25.0])
    schedule.recorded(session, clock.now())
    assert schedule.held("T1", set(), clock.now()) == "retry later"
    clock.t += cfg.surveys.retry_s
    assert schedule.held("T1", set(), clock.now()) is None
    assert schedule.next(set(), clock.now()).tank == "T2"  # T1's record dates its next survey a week on
    schedule.current = None
    clock.t = t("2026-06-08T10:00")
    assert schedule.next(set(), clock.now()).tank == "T1"


def test_a_captured_survey_that_recorded_no_fish_waits_retry_s_not_a_week(parts):
    cfg, store, rations, clock = parts
    schedule = Schedule(cfg, store, rations, clock)
    clock.t = t("2026-06-01T10:05")
    session = schedule.next(set(), clock.now())
    schedule.ended(session, "captured", clock.now())
    schedule.recorded(session, clock.now())                  # measured nothing: the ledger has no survey
    assert schedule.next(set(), clock.now()) is None
    clock.t += cfg.surveys.retry_s
    assert schedule.next(set(), clock.now()).tank == "T1"


@pytest.mark.parametrize("fish, weighs", [(1, False), (9, False), (10, True), (25, True)])
def test_a_captured_survey_that_counted_too_few_fish_to_weigh_the_tank_is_tried_again(tmp_path, fish, weighs):
    """``min_weighed_fish`` 10: a survey of fewer (a reef hid most fish) is tried again ``retry_s``
    on, as one that counted none; one of 10 or more dates the next a week on (T2, surveyed daily,
    paused throughout)."""
    cfg = config(min_weighed_fish=10)
    store = Store(tmp_path / "ledger.db", cfg.surveys.min_weighed_fish)
    clock = ManualClock(t=t("2026-06-01T09:00"))
    schedule = Schedule(cfg, store, Rations(cfg, load_species(), store), clock)
    clock.t = t("2026-06-01T10:05")
    session = schedule.next({"T2"}, clock.now())
    assert session.tank == "T1"
    schedule.ended(session, "captured", clock.now())
    store.add_survey("T1", clock.now() + 60, "sparus_aurata", "x", [10.0] * fish, [20.0] * fish)
    clock.t += 120
    schedule.recorded(session, clock.now())
    clock.t += cfg.surveys.retry_s
    again = schedule.next({"T2"}, clock.now())
    assert (again is None) is weighs, again
    clock.t = t("2026-06-08T10:05")
    assert schedule.next({"T2"}, clock.now()).tank == "T1"          # a week on, due whichever it was


def _night_tank(tmp_path, offset_h: float):
    cfg = Config(tanks=[TankConfig(id="T1", stock=1000, mean_weight_g=20, position_m=3, sensors=["a"],
                                   survey=SurveySchedule(every_days=7, at="22:00", pairs=12))],
                 path="<test>", utc_offset_h=offset_h, devices={"stereo": {"kind": "stereo_camera", "driver": "sim"}})
    store = Store(tmp_path / "ledger.db")
    clock = ManualClock(t=t("2026-06-01T21:00") - offset_h * 3600)
    return cfg, store, Schedule(cfg, store, Rations(cfg, load_species(), store), clock), clock


@pytest.mark.parametrize("offset_h", [0.0, 5.5, -3.0])
def test_blind_cameras_are_tried_again_once_then_at_the_tank_s_hour_each_day(tmp_path, offset_h):
    """A tank whose visits count no fish or fail: tried again ``retry_s`` on, then only at its own
    (night) survey hour each day — never every hour through the feeding day — until a survey counts
    fish (then weekly again) or an operator asks for one (then ``retry_s`` again)."""
    cfg, store, schedule, clock = _night_tank(tmp_path, offset_h)
    local = lambda iso: t(iso) - offset_h * 3600              # noqa: E731  (farm local time -> farm time)

    def visit(at: str, outcome: str, fish: list[float] | None = None):
        clock.t = local(at)
        session = schedule.next(set(), clock.now())
        assert session is not None and session.tank == "T1", at
        schedule.ended(session, outcome, clock.now())
        if outcome == "captured":
            store.add_survey("T1", clock.now(), "sparus_aurata", "test", fish or [], [25.0] * len(fish or []))
            schedule.recorded(session, clock.now())
        return session

    def idle(start: str, hours: float):
        for h in range(int(hours * 4)):
            clock.t = local(start) + h * 900
            assert schedule.next(set(), clock.now()) is None, datetime.fromtimestamp(clock.t + offset_h * 3600, UTC)

    visit("2026-06-01T22:00", "captured")                     # no fish: once more an hour on
    idle("2026-06-01T22:00", 1)
    visit("2026-06-01T23:00", "captured")                     # again: the next night at its hour
    idle("2026-06-01T23:00", 23)
    visit("2026-06-02T22:00", "failed")
    idle("2026-06-02T22:00", 24)
    visit("2026-06-03T22:00", "captured", [10.0, 11.0])      # fish: weekly from this survey
    idle("2026-06-03T22:00", 24 * 7)
    visit("2026-06-10T22:00", "captured")
    idle("2026-06-10T22:00", 1)
    visit("2026-06-10T23:00", "failed")
    clock.t = local("2026-06-11T09:00")
    assert schedule.held("T1", set(), clock.now()) == "retry later"
    assert schedule.request("T1") is None                     # an operator's: at once, and retry_s after
    visit("2026-06-11T09:00", "captured")
    idle("2026-06-11T09:00", 1)
    assert schedule.next(set(), local("2026-06-11T10:00")).tank == "T1"
    store.close()


def test_an_operator_survey_goes_first_once_per_tank(parts):
    cfg, store, rations, clock = parts
    schedule = Schedule(cfg, store, rations, clock)
    assert schedule.request("T3") is None
    assert schedule.request("T3") == "a survey of T3 is asked for already"
    session = schedule.next(set(), clock.now())
    assert (session.tank, session.pairs, session.why) == ("T3", cfg.surveys.pairs, "operator")
    assert schedule.request("T3").startswith("a survey of T3 is under way")


def test_an_operator_s_survey_outlives_a_restart_until_it_is_recorded(parts):
    """A controller killed mid-survey forgot the survey under way and those queued, though each
    operator had been told ok."""
    cfg, store, rations, clock = parts
    before = Schedule(cfg, store, rations, clock)
    assert before.request("T3", pairs=7) is None and before.request("T1") is None
    under_way = before.next(set(), clock.now())
    assert under_way.tank == "T3"
    clock.advance(60.0)
    after = Schedule(cfg, store, rations, clock)                # the restart: the same ledger
    assert [(s.tank, s.pairs, s.why) for s in after.asked.values()] == [("T3", 7, "operator"),
                                                                       ("T1", cfg.surveys.pairs, "operator")]
    t3 = after.next(set(), clock.now())
    after.ended(t3, "captured", clock.now())
    store.add_survey("T3", clock.now(), "sparus_aurata", "test", [10.0], [20.0])
    after.recorded(t3, clock.now())                             # recorded: not asked again
    t1 = after.next(set(), clock.now())
    after.ended(t1, "failed", clock.now())                      # the camera failed: tried again, still asked
    assert [tank for tank, _, _ in store.surveys_asked()] == ["T1"]
    assert list(Schedule(cfg, store, rations, clock).asked) == ["T1"]
    clock.advance(cfg.surveys.retry_s)
    t1 = after.next(set(), clock.now())
    after.ended(t1, "captured", clock.now())
    store.add_survey("T1", clock.now(), "sparus_aurata", "test", [10.0], [20.0])
    after.recorded(t1, clock.now())                             # recorded: answered at last
    assert store.surveys_asked() == []
    assert Schedule(cfg, store, rations, clock).asked == {}


def test_the_robot_s_camera_is_named_or_the_only_one():
    cfg = config()
    assert survey_camera_name(cfg) == "stereo"
    two = cfg.model_copy(update={"devices": {n: {"kind": "stereo_camera", "driver": "sim"} for n in ("a", "b")}})
    with pytest.raises(BadInput, match="surveys.camera: 2 stereo cameras: name the robot's"):
        survey_camera_name(two)
    none = cfg.model_copy(update={"devices": {}})
    with pytest.raises(BadInput, match=r"^<test>: tanks.0.survey: scheduled surveys need a stereo_camera device$"):
        survey_camera_name(none)
    wrong = cfg.model_copy(update={"surveys": SurveysConfig(camera="left")})
    with pytest.raises(BadInput, match="surveys.camera: no stereo_camera device 'left'"):
        survey_camera_name(wrong)


def test_start_survey_over_zenoh_or_modbus_asks_the_robot_and_is_audited(tmp_path):
    store = Store(tmp_path / "ledger.db")
    farm = Farm(store)
    pokes = []
    stops = SurveyStops(farm.cfg, farm.clock, camera=None, store=store, rations=farm.rations, alarms=farm.alarms,
                        species={})
    stops.poke = lambda: pokes.append(1)
    farm.survey_stops = stops

    async def go():
        o = Overrides(farm)
        replies = [await o.apply("start-survey", {"tank": "T1", "operator": "ana", "reason": "weekly"}, user="ana"),
                   await o.apply("start-survey", {"tank": "T1"}, origin="modbus 127.0.0.1:5"),
                   await o.apply("pause", {"tank": "T2"}),
                   await o.apply("start-survey", {"tank": "T2"})]
        await asyncio.sleep(0)
        return replies
    replies = asyncio.run(go())
    assert replies == [{"ok": True}, {"ok": True, "note": "a survey of T1 is asked for already"}, {"ok": True},
                       {"ok": False, "error": "tank: T2 is paused (resume it first)"}]
    assert list(stops.schedule.asked) == ["T1"] and pokes
    rows = [dict(r) for r in store.audit() if r["command"] == "start-survey"]
    assert [(r["user"], r["ok"], r["origin"]) for r in rows] == [("ana", 1, "zenoh"), (None, 1, "modbus 127.0.0.1:5"),
                                                                  (None, 0, "zenoh")]
    store.close()


def _farm_with_stops(tmp_path):
    """(store, farm, its survey stops) of a controller stand-in whose robot is asked nothing."""
    store = Store(tmp_path / "ledger.db")
    farm = Farm(store)
    stops = SurveyStops(farm.cfg, farm.clock, camera=None, store=store, rations=farm.rations, alarms=farm.alarms,
                        species={})
    stops.poke = lambda: None
    farm.survey_stops = stops
    return store, farm, stops


def test_start_survey_says_what_will_hold_it_back(tmp_path):
    """Taken with a bare ok while the robot was e-stopped, or for a tank fasting today: it waits."""
    store, farm, stops = _farm_with_stops(tmp_path)

    async def go():
        o = Overrides(farm)
        farm.rations.set("T2", farm.clock.now(), 0.0, "operator")
        fasting = await o.apply("start-survey", {"tank": "T2"})
        farm.robot.state = "estop"
        stopped = await o.apply("start-survey", {"tank": "T1"})
        return fasting, stopped
    fasting, stopped = asyncio.run(go())
    assert fasting == {"ok": True, "note": "asked for: T2 is fasting today (an operator's 0 g ration): it waits "
                                           "for tomorrow"}
    assert stopped == {"ok": True, "note": "asked for: it starts once the e-stop is reset"}
    assert list(stops.schedule.asked) == ["T2", "T1"]
    store.close()


def test_start_survey_of_a_tank_with_no_fish_left_is_refused(tmp_path):
    """All its fish harvested (or moved out): a visit would count nothing and raise the no-fish
    warning; refused, naming the tank. One fish left is still surveyed."""
    store, farm, stops = _farm_with_stops(tmp_path)
    stock = {t.id: t.stock for t in farm.cfg.tanks}

    async def go():
        o = Overrides(farm)
        out = [await o.apply("harvest", {"tank": "T1", "count": stock["T1"] - 1, "operator": "ana", "reason": "sold"}),
               await o.apply("start-survey", {"tank": "T1"})]
        stops.schedule.asked.clear()
        out += [await o.apply("transfer", {"tank": "T1", "count": 1, "to": "T2", "operator": "ana", "reason": "x"}),
                await o.apply("start-survey", {"tank": "T1"}), await o.apply("start-survey", {"tank": "T2"})]
        # nor food for it: an operator's feed, or a ration above 0 g (0 g says what is so)
        out += [await o.apply("feed", {"tank": "T1", "grams": 40, "operator": "ana", "reason": "x"}),
                await o.apply("ration", {"tank": "T1", "grams": 500, "operator": "ana", "reason": "x"}),
                await o.apply("ration", {"tank": "T1", "grams": 0, "operator": "ana", "reason": "x"})]
        return out
    harvested, one_left, moved, empty, other, feed, ration, nothing = asyncio.run(go())
    assert harvested["ok"] and moved["ok"] and one_left == {"ok": True} and other == {"ok": True}
    refused = {"ok": False, "error": "tank: T1 holds no fish (its stock events took them all)"}
    assert empty == feed == ration == refused and nothing == {"ok": True}
    assert list(stops.schedule.asked) == ["T2"]
    store.close()


def test_a_survey_held_by_a_pause_says_so_in_the_status(tmp_path):
    """Its session stays current while its tank is paused: status showed it as under way."""
    store, farm, stops = _farm_with_stops(tmp_path)

    async def go():
        o = Overrides(farm)
        await o.apply("start-survey", {"tank": "T1"})
        assert stops.schedule.next(set(), farm.clock.now()).tank == "T1"
        running = stops.snapshot()["current"]["held"]
        await o.apply("pause", {"tank": "T1", "operator": "ana", "reason": "grading"})
        paused = stops.snapshot()["current"]
        await o.apply("resume", {"tank": "T1", "operator": "ana", "reason": "done"})
        return running, paused, stops.snapshot()["current"]["held"]
    running, paused, resumed = asyncio.run(go())
    assert running is None and resumed is None
    assert (paused["tank"], paused["held"]) == ("T1", "paused")
    store.close()


@pytest.mark.parametrize("why", ["operator", "schedule"])
def test_a_survey_whose_tank_is_paused_midway_is_put_aside_not_holding_the_others(parts, why):
    """An operator paused the tank under way (grading, days): every other survey, scheduled ones
    too, waited for its resume. It is put aside, its pairs kept, the others go on, and it goes on
    where it was once the tank may be surveyed again."""
    cfg, store, rations, clock = parts
    schedule = Schedule(cfg, store, rations, clock)
    clock.t = t("2026-06-01T10:05")
    if why == "operator":
        schedule.request("T3")
    first = schedule.next(set(), clock.now())
    assert (first.tank, first.why) == ("T3" if why == "operator" else "T1", why)
    first.captured = 4
    schedule.ended(first, "preempted", clock.now())                   # a demand took the robot away
    clock.t = t("2026-06-01T11:05")
    other = schedule.next({first.tank}, clock.now())                  # its tank paused meanwhile
    assert other is not None and other.tank != first.tank and schedule.current is other
    schedule.ended(other, "captured", clock.now())
    store.add_survey(other.tank, clock.now(), "sparus_aurata", "test", [10.0] * 12, [25.0] * 12)
    schedule.recorded(other, clock.now())
    nxt = schedule.next({first.tank}, clock.now())
    assert nxt is None or nxt.tank != first.tank                      # still paused: still aside
    if nxt is not None:
        schedule.ended(nxt, "captured", clock.now())
        schedule.recorded(nxt, clock.now())
    back = schedule.next(set(), clock.now())                          # resumed: the same session, its pairs
    assert back is first and back.captured == 4


def test_an_operator_s_survey_whose_camera_failed_is_tried_again_not_dropped(parts):
    """"survey of T1 failed (1 in a row): tried again in 0.0 h" -- and it never was: an operator's
    survey was dropped at its camera's failure, the pairs it had captured with it. It is tried again
    retry_s later, as a scheduled one is, and goes on with them."""
    cfg, store, rations, clock = parts
    schedule = Schedule(cfg, store, rations, clock)
    schedule.request("T3", pairs=40)
    session = schedule.next(set(), clock.now())
    session.captured, session.failed = 8, "no frame (source gone or silent)"
    schedule.ended(session, "failed", clock.now())
    assert schedule.next(set(), clock.now()) is None                  # not before retry_s
    assert [tank for tank, _, _ in store.surveys_asked()] == ["T3"]   # still asked, a restart too
    clock.t += cfg.surveys.retry_s
    again = schedule.next(set(), clock.now())
    assert again is session and again.captured == 8 and again.failed is None
