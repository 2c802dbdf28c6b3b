"""Issue 8's commands through ``Overrides.apply``, the one entry every override takes: pause and
resume, alarm acknowledge, stock events, the stubs; each refusal names its field and changes
nothing; every command, accepted or refused, is one audit row. Real ledger, rations and alarms;
the robot a recorder (tests/controller/override_rig.py)."""
from __future__ import annotations

import asyncio
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.app import Controller
from controller.feeding.rations import Rations
from controller.override_models import AUDIT_PAYLOAD_MAX, COUNT_MAX
from controller.overrides import COMMANDS, NOT_YET, Overrides
from controller.store import Store
from controller.text import has_control
from tests.controller.override_rig import STOCK, TANKS, Farm


@pytest.fixture
def farm(tmp_path):
    store = Store(tmp_path / "ledger.db")
    yield Farm(store)
    store.close()


def apply(farm, command, payload, **kw):
    async def go():
        reply = await Overrides(farm).apply(command, payload, **kw)
        await asyncio.sleep(0)          # the e-stop's audit row is written just after its reply
        return reply
    return asyncio.run(go())


def audit(farm) -> list[dict]:
    return [dict(r) for r in farm.store.audit()]


def status(farm) -> dict:
    """The real Controller.status over the farm's parts (the robot not up yet)."""
    parts = SimpleNamespace(cfg=farm.cfg, clock=farm.clock, robot=None, rations=farm.rations,
                            store=farm.store, alarms=farm.alarms, started_monotonic=time.monotonic())
    return Controller.status(parts)


# ---------------------------------------------------------------- pause / resume

def test_pause_is_kept_in_the_ledger_shown_in_status_and_survives_a_restart(farm, tmp_path):
    assert apply(farm, "pause", {"tank": "T2", "operator": "ana", "reason": "grading"}) == {"ok": True}
    assert farm.robot.calls == [("pause", "T2")]
    assert {t: s["paused"] for t, s in status(farm)["tanks"].items()} == {"T1": False, "T2": True, "12": False}
    assert apply(farm, "pause", {"tank": "T2"}) == {"ok": True, "note": "tank T2 was paused already"}
    farm.store.close()
    farm = Farm(Store(tmp_path / "ledger.db"))                      # a restart
    assert set(farm.store.paused_tanks()) == {"T2"} and farm.store.paused_tanks()["T2"]["who"] == "ana (claimed)"
    assert status(farm)["tanks"]["T2"]["paused"]
    assert apply(farm, "feed", {"tank": "T2", "grams": 20}) == {"ok": False,
                                                                 "error": "tank: T2 is paused (resume it first)"}
    assert apply(farm, "resume", {"tank": "T2"}, user="bob") == {"ok": True}
    assert farm.store.paused_tanks() == {} and not status(farm)["tanks"]["T2"]["paused"]
    assert apply(farm, "resume", {"tank": "T2"}) == {"ok": True, "note": "tank T2 was not paused"}
    assert apply(farm, "feed", {"tank": "T2", "grams": 20})["ok"] is True
    farm.store.close()


# ---------------------------------------------------------------- stock events

def test_stock_events_change_the_stock_the_rations_use(farm):
    now = farm.clock.now()
    planned = farm.rations.today("T1", now).grams
    assert status(farm)["tanks"]["T1"]["stock"] == STOCK
    assert apply(farm, "mortality", {"tank": "T1", "count": 100}) == {"ok": True, "stock": {"T1": STOCK - 100}}
    assert farm.rations.today("T1", now).grams == pytest.approx(planned * (STOCK - 100) / STOCK)
    assert apply(farm, "harvest", {"tank": "T1", "count": 400}) == {"ok": True, "stock": {"T1": STOCK - 500}}
    assert apply(farm, "transfer", {"tank": "T1", "to": "12", "count": 500}) == {
        "ok": True, "stock": {"T1": STOCK - 1000, "12": STOCK + 500}}
    assert farm.rations.today("12", now).grams == pytest.approx(planned * (STOCK + 500) / STOCK)
    assert farm.published == ["T1", "T1", "T1", "12"]
    assert {t: s["stock"] for t, s in status(farm)["tanks"].items()} == {"T1": 1000, "T2": STOCK, "12": 2500}
    # an operator's ration stands: the stock still changes, the ration does not
    assert apply(farm, "ration", {"tank": "T2", "grams": 123.0})["ok"]
    assert apply(farm, "mortality", {"tank": "T2", "count": 1})["ok"]
    assert farm.rations.today("T2", now).grams == 123.0 and farm.rations.stock("T2") == STOCK - 1
    # every fish may go, not one more
    assert apply(farm, "harvest", {"tank": "T1", "count": 1001}) == {
        "ok": False, "error": "count: more than the 1000 fish in tank T1"}
    assert apply(farm, "harvest", {"tank": "T1", "count": 1000}) == {"ok": True, "stock": {"T1": 0}}
    assert farm.rations.today("T1", now).grams == 0
    # an empty tank is said so, not "more than the 0 fish" (an outside tester)
    for command, payload in (("mortality", {"tank": "T1", "count": 1}),
                             ("transfer", {"tank": "T1", "to": "T2", "count": 1})):
        assert apply(farm, command, payload) == {
            "ok": False, "error": "tank: T1 holds no fish (its stock events took them all)"}
    assert [(r["tank"], r["kind"], r["count"], r["to_tank"]) for r in farm.store.stock_events()] == [
        ("T1", "mortality", 100, None), ("T1", "harvest", 400, None), ("T1", "transfer", 500, "12"),
        ("T2", "mortality", 1, None), ("T1", "harvest", 1000, None)]


COUNT_FAULTS = [
    (0, "count: must be more than 0"), (-5, "count: must be more than 0"),
    (COUNT_MAX + 1, f"count: must be at most {COUNT_MAX}"), (10**400, f"count: must be at most {COUNT_MAX}"),
    (2.0, "count: must be an integer, not a number"), ("5", "count: must be an integer, not a string"),
    (True, "count: must be an integer, not a boolean"), (None, "count: must be an integer, not null"),
    ([5], "count: must be an integer, not an array"), (STOCK + 1, f"count: more than the {STOCK} fish in tank T1"),
]


@pytest.mark.parametrize("command", ["mortality", "harvest", "transfer"])
@pytest.mark.parametrize("count, error", COUNT_FAULTS, ids=[repr(c)[:20] for c, _ in COUNT_FAULTS])
def test_a_count_that_is_no_count_of_these_fish_is_refused(farm, command, count, error):
    payload = {"tank": "T1", "count": count} | ({"to": "T2"} if command == "transfer" else {})
    before = farm.acted()
    assert apply(farm, command, payload) == {"ok": False, "error": error}
    assert farm.acted() == before and farm.rations.stock("T1") == STOCK


@pytest.mark.parametrize("command, payload, error", [
    ("mortality", {"tank": "T9", "count": 1}, "tank: no tank 'T9'"),
    ("mortality", {"tank": "T 1", "count": 1}, "tank: letters, digits, _ and - only (1 to 32)"),
    ("mortality", {"tank": 1, "count": 1}, "tank: must be a string, not a number"),
    ("mortality", {"count": 1}, "tank: required"),
    ("harvest", {"tank": "T1"}, "count: required"),
    ("harvest", {"tank": "T1", "count": 1, "kg": 3}, "kg: unknown field"),
    ("transfer", {"tank": "T1", "to": "T1", "count": 1}, "to: the same tank as tank"),
    ("transfer", {"tank": "T1", "to": "T9", "count": 1}, "to: no tank 'T9'"),
    ("transfer", {"tank": "T9", "to": "T1", "count": 1}, "tank: no tank 'T9'"),
    ("transfer", {"tank": "T1", "count": 1}, "to: required"),
    ("pause", {"tank": "T9"}, "tank: no tank 'T9'"),
    ("pause", {}, "tank: required"),
    ("resume", {"tank": "T1", "until": "noon"}, "until: unknown field"),
    ("ack", {}, 'source: required (or "all": true)'),
    ("ack", {"all": False}, 'source: required (or "all": true)'),
    ("ack", {"all": True, "source": "feeder"}, 'source: not with "all": true'),
    ("ack", {"all": "yes"}, "all: must be true or false, not a string"),
    ("ack", {"source": "nobody"}, "source: no such alarm"),
    ("ack", {"source": "feeder\n"}, "source: control characters (newline, carriage return, escape...) are not allowed"),
    ("ack", {"source": "x" * 101}, "source: longer than 100 characters"),
    ("start-survey", {"tank": "T1"}, "command: no survey camera in this controller (farm.toml has no "
                                     "stereo_camera device)"),
    ("start-survey", {"tank": "T9"}, "tank: no tank 'T9'"),
    ("start-survey", {"tank": 3}, "tank: must be a string, not a number"),
    ("cleaner-start", {}, "command: no pond cleaner in this controller (farm.toml has no [cleaning] section)"),
    ("cleaner-stop", {"operator": "ana"},
     "command: no pond cleaner in this controller (farm.toml has no [cleaning] section)"),
    ("cleaner-return", {"speed": 1}, "speed: unknown field"),
    ("reset", [1, 2], "payload: must be a JSON object, not an array"),
    ("feed", "T1 40", "payload: must be a JSON object, not a string"),
    ("launch", {}, "command: unknown command 'launch'; known: " + ", ".join(COMMANDS)),
])
def test_refusals_name_their_field_and_change_nothing(farm, command, payload, error):
    farm.alarms.raise_("feeder", "fault: rail: timeout", kind="fault")
    before = farm.acted()
    assert apply(farm, command, payload) == {"ok": False, "error": error}
    assert farm.acted() == before
    [row] = audit(farm)
    assert (row["command"], row["ok"], row["result"]) == (command, 0, error)


@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_generated_stock_events_move_exactly_the_fish_they_name(data):
    """Over the whole range, a few events in a row on a fresh ledger: a count is taken iff it is an
    integer 1..fish held; the stock moves by exactly it; anything else moves nothing."""
    with tempfile.TemporaryDirectory() as tmp:
        farm = Farm(Store(Path(tmp) / "ledger.db"))
        try:
            for _ in range(data.draw(st.integers(1, 4))):
                _one_stock_event(farm, data)
            assert Store(farm.store.path).stock_events() == farm.store.stock_events()   # committed
        finally:
            farm.store.close()


def _one_stock_event(farm, data) -> None:
    command = data.draw(st.sampled_from(["mortality", "harvest", "transfer"]))
    tank = data.draw(st.sampled_from(TANKS))
    held = {t: farm.rations.stock(t) for t in TANKS}
    count = data.draw(st.one_of(st.integers(-10, 2 * STOCK), st.integers(), st.floats(),
                                st.booleans(), st.text(max_size=5), st.none()))
    payload = {"tank": tank, "count": count}
    to = data.draw(st.sampled_from(TANKS)) if command == "transfer" else None
    if to is not None:
        payload["to"] = to
    valid = type(count) is int and 0 < count <= held[tank] and to != tank
    reply = apply(farm, command, payload)
    after = {t: farm.rations.stock(t) for t in TANKS}
    assert reply["ok"] is valid, (payload, reply)
    expected = dict(held)
    if valid:
        expected[tank] -= count
        if to is not None:
            expected[to] += count
    else:
        assert reply["error"].split(":")[0] in ("count", "to"), reply
    assert after == expected
    fresh = Rations(farm.cfg, farm.rations.species, farm.store)   # a restart: config + the ledger's events
    assert {t: fresh.stock(t) for t in TANKS} == after


# ---------------------------------------------------------------- acknowledge

def test_ack_names_who_and_leaves_a_standing_alarm_standing(farm):
    farm.alarms.raise_("device/rail", "no status frame", kind="unreachable")
    farm.alarms.raise_("device/rail", "cannot open", kind="config")
    farm.alarms.raise_("feeder", "fault", kind="fault")
    assert apply(farm, "ack", {"source": "device/rail", "kind": "nope"}) == {"ok": False,
                                                                            "error": "kind: no such alarm"}
    assert apply(farm, "ack", {"source": "device/rail", "kind": "config"}, user="bob") == {
        "ok": True, "acked": [{"source": "device/rail", "kind": "config"}]}
    shown = {(a["source"], a["kind"]): a for a in status(farm)["alarms"]}
    assert shown["device/rail", "config"]["acked_by"] == "bob" and shown["device/rail", "config"]["active"]
    assert shown["device/rail", "unreachable"]["acked"] is False
    assert apply(farm, "ack", {"source": "device/rail", "operator": "ana"}) == {
        "ok": True, "acked": [{"source": "device/rail", "kind": "unreachable"}]}
    assert farm.alarms.known["device/rail", "unreachable"].acked_by == "ana (claimed)"
    assert apply(farm, "ack", {"source": "device/rail"}) == {"ok": True, "acked": []}     # nothing left
    assert apply(farm, "ack", {"all": True}) == {"ok": True, "acked": [{"source": "feeder", "kind": "fault"}]}
    assert len(farm.alarms.active) == 3           # acknowledged, still standing
    [row] = [r for r in farm.store.alarm_states() if r["kind"] == "config"]
    assert (row["acked_by"], row["active"]) == ("bob", 1)


# ---------------------------------------------------------------- the audit

def test_every_command_accepted_or_refused_is_one_audit_row(farm):
    farm.clock.advance(10.0)
    t = farm.clock.now()
    apply(farm, "feed", {"tank": "T1", "grams": 20, "operator": "ana", "reason": "check"}, user="op1",
          origin="modbus 127.0.0.1:50000")
    apply(farm, "feed", {"tank": "T1", "grams": 2000, "operator": "eve"})
    apply(farm, "estop", ["not", "an", "object"], user="op2")
    apply(farm, "cleaner-start", {})
    rows = audit(farm)
    assert [(r["t"], r["user"], r["operator"], r["command"], r["origin"], r["ok"], r["result"]) for r in rows] == [
        (t, "op1", "ana", "feed", "modbus 127.0.0.1:50000", 1, "ok"),
        (t, None, "eve", "feed", "zenoh", 0, "grams: more than one portion, feeding.portion_g (60 g)"),
        (t, "op2", None, "estop", "zenoh", 1, "ok"),
        (t, None, None, "cleaner-start", "zenoh", 0,
         "command: no pond cleaner in this controller (farm.toml has no [cleaning] section)"),
    ]
    assert rows[0]["payload"] == '{"tank":"T1","grams":20,"operator":"ana","reason":"check"}'
    assert rows[0]["reply"] == '{"grams":20.0,"demand":1}' and rows[2]["payload"] == '["not","an","object"]'
    assert farm.estops == ["operator op2"]        # the e-stop names the authenticated user


def test_audit_payloads_are_bounded_and_escaped(farm):
    forged = "x\n2026-05-28T06:00:00Z INFO fishfarm: e-stop released\x1b[2J" + "y" * 5_000_000
    for command in ("estop", "reset", "ack"):
        apply(farm, command, {"operator": "ana\rbob", "reason": forged, "deep": [[[[[[1]]]]]], "n": 10**300})
    for row in audit(farm):
        for field in ("payload", "result", "operator"):
            assert len(row[field]) <= AUDIT_PAYLOAD_MAX and not has_control(row[field]), (field, row[field][:80])
        assert row["operator"] == "ana\\rbob"


def test_every_command_of_the_plan_has_its_entry():
    """The names the Modbus map and Zenoh keys use (PLAN8.md), exactly."""
    assert set(COMMANDS) == {"estop", "reset", "manual", "feed", "ration", "settle", "pause", "resume", "ack",
                             "mortality", "harvest", "transfer", "start-survey", "cleaner-start", "cleaner-stop",
                             "cleaner-return"}
    assert set(NOT_YET) == set()


def test_the_override_command_line_sends_names_as_strings():
    """``fishfarm override transfer tank=12 to=14``: tank and alarm names stay strings, counts are numbers."""
    from controller.cli.override_cmd import parse_args
    assert parse_args(["tank=12", "to=14", "count=3", "source=7", "kind=1", "all=true"]) == {
        "tank": "12", "to": "14", "count": 3, "source": "7", "kind": "1", "all": True}


@pytest.mark.parametrize("control", ["\n", "\r", "\x1b", "\u200b", "\u2028"])
def test_a_settle_id_is_one_line_like_every_text_an_operator_sends(control):
    """An id with a newline got past the model (to the handler's 'needs a reason'): found by the
    storm of generated payloads."""
    from controller.override_models import Refused, Settle, parse
    with pytest.raises(Refused, match="^id: control characters"):
        parse(Settle, {"id": f"1a{control}b", "grams": 0.0})
    assert parse(Settle, {"id": "1a2b", "grams": 0.0}).id == "1a2b"


@pytest.mark.parametrize("state", ["estop", "idle", "moving"])
def test_manual_off_when_the_robot_is_not_in_manual_says_so(farm, state):
    """It answered a bare ok during an e-stop, as if something had been released."""
    farm.robot.state = state
    assert apply(farm, "manual", {"on": False}) == {
        "ok": True, "note": f"nothing to release: the robot is not in manual (it is {state})"}
    farm.robot.state = "manual"
    assert apply(farm, "manual", {"on": False}) == {"ok": True}


def test_a_suspect_feed_of_a_tank_no_longer_in_the_config_is_settled_and_said_so(farm):
    """A feed to T8 left suspect by a kill, T8 then taken out of the config: the settle wrote the
    ledger, then publishing T8's ration raised KeyError -- a LookupError, answered "not suspect" --
    and the critical alarm naming the feed stood for good, the settle refused every time."""
    from controller.feeding.dispensing import Dispensing
    f = farm.store.add_intent(tank="T8", date="2026-06-01", t=100.0, target_g=60, run_s=5, cycles_before=0,
                              source="demand")
    farm.store.mark_suspect(f.id, "counters reset")
    published = []
    disp = Dispensing(farm.cfg, farm.clock, SimpleNamespace(name="dispenser"), farm.store, farm.rations, farm.alarms,
                      lambda key, payload, **_: published.append(key))
    disp._alarm_suspects()
    assert "ledger" in farm.alarms.active
    farm.robot.dispensing = disp
    reply = apply(farm, "settle", {"id": f.id, "grams": 55, "reason": "weighed", "operator": "ana"})
    assert reply == {"ok": True, "phase": "done"}, reply
    assert "ledger" not in farm.alarms.active
    assert "tank/T8/feed" in published and "tank/T8/ration" not in published
    again = apply(farm, "settle", {"id": f.id, "grams": 55, "reason": "weighed", "operator": "ana"})
    assert again["ok"] is False and "is not suspect" in again["error"]
