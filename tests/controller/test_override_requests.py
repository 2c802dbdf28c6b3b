"""An override sent again under its ``request`` id is done once (controller.override_requests):
stock events, feeds and rations through ``Overrides.apply``, a restart between the two sends, two
copies in flight at once, an id reused for another command, refusals tried anew, bad ids."""
from __future__ import annotations

import asyncio

import pytest

from controller.overrides import Overrides
from controller.store import Store
from tests.controller.override_rig import STOCK, Farm


@pytest.fixture
def farm(tmp_path):
    store = Store(tmp_path / "ledger.db")
    yield Farm(store)
    store.close()


def send(farm, command, payload, overrides=None):
    async def go():
        return await (overrides or Overrides(farm)).apply(command, payload)
    return asyncio.run(go())


def stock_rows(farm):
    return [(r["tank"], r["kind"], r["count"], r["to_tank"]) for r in farm.store.stock_events()]


@pytest.mark.parametrize("command, payload, stock", [
    ("mortality", {"tank": "T1", "count": 12}, {"T1": STOCK - 12}),
    ("harvest", {"tank": "T2", "count": STOCK}, {"T2": 0}),
    ("transfer", {"tank": "T1", "to": "12", "count": 400}, {"T1": STOCK - 400, "12": STOCK + 400}),
])
def test_a_stock_event_sent_again_under_its_request_is_booked_once(farm, tmp_path, command, payload, stock):
    payload = {**payload, "request": "7d1c0b5e-2f6a-4c39-9a51-0c2d3e4f5a6b"}
    first = send(farm, command, payload)
    assert first == {"ok": True, "stock": stock}
    assert send(farm, command, payload) == {**first, "repeat": True}        # a fresh Overrides: the ledger
    farm.store.close()
    farm = Farm(Store(tmp_path / "ledger.db"))                             # a restart between the sends
    assert send(farm, command, payload) == {**first, "repeat": True}
    assert len(stock_rows(farm)) == 1
    assert {t: farm.rations.stock(t) for t in stock} == stock
    # without an id it is another event
    again = {k: v for k, v in payload.items() if k != "request"}
    assert send(farm, command, again)["ok"] is (command != "harvest")          # no fish left to harvest
    assert len(stock_rows(farm)) == 1 + (command != "harvest")
    # every send is audited: the repeat with its reply's repeat
    replies = ["repeat" in (r["reply"] or "") for r in farm.store.audit()]
    assert replies == [False, True, True, False]


def test_a_feed_sent_again_is_asked_of_the_robot_once(farm):
    payload = {"tank": "T1", "grams": 30.0, "request": "feed-0001"}
    first = send(farm, "feed", payload)
    assert first["ok"] is True
    again = send(farm, "feed", payload)
    assert again == {**first, "repeat": True}
    assert [c for c in farm.robot.calls if c[0] == "on_demand"] == [("on_demand", "T1", 30.0, "operator")]
    # in the ledger as a demand of its own before it was accepted: a restart serves it
    # (hil_tests/test_operator_feed_restart.py)
    assert [(r["tank"], r["source"], r["grams"], r["outcome"]) for r in farm.store.open_demands()] == [
        ("T1", "operator", 30.0, "open")]


@pytest.mark.parametrize("outcome", ["estop", "served", "open"])
def test_a_feed_withdrawn_by_an_estop_is_no_ok_when_sent_again(farm, outcome):
    """An outside tester: a feed accepted, withdrawn by an e-stop before its portion (its demand
    closed 'estop'), sent again under its id after the reset: answered "ok", "repeat" of 50 g
    that would never go in. Served or still waiting, the repeat stands."""
    payload = {"tank": "T1", "grams": 30.0, "request": "feed-0002"}
    first = send(farm, "feed", payload)
    assert first["ok"] is True and isinstance(first["demand"], int)
    if outcome != "open":
        farm.store.close_demand(first["demand"], outcome)
    again = send(farm, "feed", payload)
    if outcome == "estop":
        assert again["ok"] is False and again["withdrawn"] is True and "e-stop" in again["error"], again
        assert "new request id" in again["error"]
    else:
        assert again == {**first, "repeat": True}
    assert [c for c in farm.robot.calls if c[0] == "on_demand"] == [("on_demand", "T1", 30.0, "operator")]


def test_two_copies_in_flight_at_once_are_carried_out_once(farm):
    class Slow(Overrides):
        async def mortality(self, payload, by=None):
            await asyncio.sleep(0.01)          # the second copy arrives while the first is acting
            return await super().mortality(payload, by)

    async def go():
        o = Slow(farm)
        payload = {"tank": "T1", "count": 5, "request": "r-1"}
        return await asyncio.gather(*(o.apply("mortality", payload) for _ in range(3)))
    replies = asyncio.run(go())
    assert sorted(r.get("repeat", False) for r in replies) == [False, True, True]
    assert all(r["stock"] == {"T1": STOCK - 5} for r in replies)
    assert stock_rows(farm) == [("T1", "mortality", 5, None)]


def test_an_id_used_by_another_command_is_refused_and_nothing_is_done(farm):
    assert send(farm, "mortality", {"tank": "T1", "count": 5, "request": "r-2"})["ok"]
    reply = send(farm, "harvest", {"tank": "T1", "count": 5, "request": "r-2"})
    assert reply == {"ok": False, "error": "request: already the id of a mortality override"}
    assert stock_rows(farm) == [("T1", "mortality", 5, None)]


def test_an_id_sent_again_with_other_values_is_refused_and_nothing_is_done(farm, tmp_path):
    """It was answered ok as a repeat: the six dead fish were never booked and their sender was
    told they were. Kept across a restart; the same values again are still a repeat."""
    first = send(farm, "mortality", {"tank": "T1", "count": 5, "request": "r-4"})
    for other in ({"tank": "T1", "count": 6}, {"tank": "T2", "count": 5}):
        reply = send(farm, "mortality", {**other, "request": "r-4"})
        assert reply == {"ok": False, "error": "request: already the id of a mortality override with other "
                                               "values (a new request needs a new id)"}
    farm.store.close()
    farm = Farm(Store(tmp_path / "ledger.db"))
    assert send(farm, "mortality", {"tank": "T1", "count": 6, "request": "r-4"})["ok"] is False
    assert send(farm, "mortality", {"tank": "T1", "count": 5, "request": "r-4"}) == {**first, "repeat": True}
    assert stock_rows(farm) == [("T1", "mortality", 5, None)]


def test_a_refused_request_is_tried_anew_when_sent_again(farm):
    payload = {"tank": "T1", "count": STOCK + 1, "request": "r-3"}
    assert send(farm, "harvest", payload)["ok"] is False
    assert send(farm, "mortality", {"tank": "T1", "count": 1})["ok"]       # the stock changes meanwhile
    assert send(farm, "harvest", {**payload, "count": STOCK - 1}) == {"ok": True, "stock": {"T1": 0}}
    assert send(farm, "harvest", {**payload, "count": STOCK - 1})["repeat"] is True


NO_ID = "request: printable ASCII without spaces only (1 to 64)"


@pytest.mark.parametrize("request_id, error", [
    ("", NO_ID), ("a b", NO_ID), ("x" * 65, NO_ID), ("é", NO_ID), ("a\nb", NO_ID),
    (7, "request: must be a string, not a number"), (None, None),
])
def test_a_request_that_is_no_id_is_refused_by_name(farm, request_id, error):
    reply = send(farm, "mortality", {"tank": "T1", "count": 1, "request": request_id})
    if error is None:                          # null: no id, as if absent
        assert reply["ok"] is True
    else:
        assert reply["ok"] is False and reply["error"].startswith(error), reply
        assert stock_rows(farm) == []


def test_an_estop_is_carried_out_every_time_whatever_its_request(farm):
    for _ in range(2):
        assert send(farm, "estop", {"request": "e-1"})["ok"] is True
    assert len(farm.estops) == 2


def test_a_command_done_while_the_ledger_cannot_remember_its_id_is_answered_done(farm):
    """A reset needs no ledger and is carried out while the ledger cannot be written (another
    process's lock, a full disk); remembering its id then fails. It was answered "ledger: cannot be
    written; try again once it can" — of a reset already done. It is answered ok, with a note that
    the id is not remembered; a stock event, which is the ledger's, is still refused."""
    import sqlite3
    hold = sqlite3.connect(str(farm.store.path), isolation_level=None, timeout=30)
    farm.store.db.execute("PRAGMA busy_timeout=0")
    hold.execute("BEGIN IMMEDIATE")
    try:
        overrides = Overrides(farm)
        reply = send(farm, "reset", {"request": "reset-1"}, overrides)
        assert reply["ok"] is True and "request reset-1 is not remembered" in reply["note"], reply
        assert farm.robot.calls.count(("operator_reset",)) == 1
        reply = send(farm, "mortality", {"tank": "T1", "count": 1, "request": "m-1"}, overrides)
        assert reply["ok"] is False and reply["error"].startswith("ledger: cannot be written"), reply
    finally:
        hold.execute("ROLLBACK")
        hold.close()
    assert send(farm, "mortality", {"tank": "T1", "count": 1, "request": "m-1"})["ok"] is True
