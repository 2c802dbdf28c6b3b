"""Operator overrides, generated: payloads sent as raw JSON over a real Zenoh session to the real
``Overrides`` on a real ``Bus``, with real rations on a real SQLite ledger. The robot is a recorder:
whatever an override makes it do is written down, so "nothing acted on" is checked, not assumed.

Each faulty payload is a valid one with exactly one field spoiled, as the issue lists the ways:
wrong JSON type, non-finite, out of range, unknown, given twice, too long, control characters.
The refusal must name that field; the robot and the ledger must not have moved."""
from __future__ import annotations

import asyncio
import json
import logging
import math
import threading

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.alarms import TEXT_MAX
from controller.bus import Bus, decode
from controller.config import BusConfig
from controller.override_models import COUNT_MAX, SOURCE_MAX
from controller.overrides import OPERATOR_MAX, RATION_MAX_G, REASON_MAX, Overrides
from controller.store import Store
from controller.text import has_control, printable
from hil_tests.ports import free_port
from tests.controller.override_rig import FEEDING, TANKS, Farm

WAIT_S = 10.0


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    store = Store(tmp_path_factory.mktemp("ledger") / "ledger.db")
    farm = Farm(store)
    farm.alarms.raise_("pump", "stopped", kind="power")      # an alarm an ``ack`` may name
    server = Bus(BusConfig(mode="peer", listen=[endpoint]), "demo", loop=loop)
    Overrides(farm).declare(server)
    client = Bus.client(endpoint, timeout_s=WAIT_S)
    yield farm, client
    client.close()
    server.close()
    store.close()
    loop.call_soon_threadsafe(loop.stop)
    thread.join(5)
    loop.close()


def ask(client, command: str, body: bytes) -> dict:
    replies = [json.loads(r.ok.payload.to_bytes()) for r in
               client.session.get(f"farm/demo/override/{command}", payload=body, timeout=WAIT_S)]
    assert len(replies) == 1, replies
    return replies[0]


def as_json(pairs: list[tuple[str, str]]) -> bytes:
    """An object from (key, raw JSON value) pairs, in order, repeats kept: the wire as sent."""
    return ("{" + ",".join(f"{json.dumps(k)}:{v}" for k, v in pairs) + "}").encode()


# ---------------------------------------------------------------- what is valid

# README "Operator guide": no controls, no format characters (Cf), no variation selectors, fillers or
# braille blank (nor unassigned code points: the default-ignorable blocks hold some)
INVISIBLE = ("\u034f\u115f\u1160\u17b4\u17b5\u180b\u180c\u180d\u180f\u2800\u3164\uffa0"
             + "".join(map(chr, range(0xFE00, 0xFE10))) + "".join(map(chr, range(0xE0100, 0xE01F0))))
TEXT_CHARS = st.characters(codec="utf-8", exclude_categories=("Cc", "Cs", "Zl", "Zp", "Cf", "Cn"),
                           exclude_characters=INVISIBLE)
operators = st.text(TEXT_CHARS, min_size=1, max_size=OPERATOR_MAX)
reasons = st.text(TEXT_CHARS, max_size=REASON_MAX)
numbers_in = lambda lo, hi: st.one_of(st.floats(lo, hi), st.integers(int(lo) + 1, int(hi)))  # noqa: E731

ORIGINAL = {  # command -> field -> strategy of a valid value: the commands that act on the robot
    "feed": {"tank": st.sampled_from(TANKS), "grams": numbers_in(FEEDING.min_portion_g, FEEDING.portion_g)},
    "ration": {"tank": st.sampled_from(TANKS), "grams": numbers_in(0, RATION_MAX_G)},
    "manual": {"on": st.booleans()},
    "reset": {},
}
VALID = {**ORIGINAL,  # and issue 8's (a spoilt field of theirs is refused before anything reads the ledger)
         "pause": {"tank": st.sampled_from(TANKS)}, "resume": {"tank": st.sampled_from(TANKS)},
         "ack": {"source": st.just("pump")},
         "mortality": {"tank": st.sampled_from(TANKS), "count": st.integers(1, 10)},
         "harvest": {"tank": st.sampled_from(TANKS), "count": st.integers(1, 10)},
         "transfer": {"tank": st.just("T1"), "to": st.just("T2"), "count": st.integers(1, 10)}}
OPTIONAL = {"operator": operators, "reason": reasons}
KINDS = {"tank": "string", "operator": "string", "reason": "string", "grams": "number", "on": "boolean",
         "to": "string", "source": "string", "count": "integer"}


@st.composite
def valid_payloads(draw, command):
    pairs = {f: draw(s) for f, s in VALID[command].items()}
    for field, strategy in OPTIONAL.items():
        if draw(st.booleans()):
            pairs[field] = draw(strategy)
    return pairs


# ---------------------------------------------------------------- ways to spoil one field

json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False)
                           | st.text(max_size=10), lambda inner: st.lists(inner, max_size=3)
                           | st.dictionaries(st.text(max_size=5), inner, max_size=3), max_leaves=6)
CONTROL = st.sampled_from(["\n", "\r", "\x1b", "\x00", "\x7f", "\x85", "\u2028", "\u202e"])


def wrong_types(kind):
    anything = json_values.filter(lambda v: not _is(kind, v))
    if kind == "number":
        numerals = st.floats(allow_nan=False, allow_infinity=False).map(repr) | st.integers().map(str)
        return st.one_of(anything, numerals, st.booleans())
    if kind == "boolean":
        return st.one_of(anything, st.sampled_from(["yes", "true", "on", "1"]), st.integers(0, 1))
    if kind == "integer":       # a fish count: 2.0 is no count, nor "2"
        return st.one_of(anything, st.integers(-5, 5).map(float), st.integers().map(str), st.booleans())
    return st.one_of(anything, st.integers(), st.booleans())


def _is(kind, v) -> bool:
    return {"string": isinstance(v, str), "boolean": isinstance(v, bool),
            "number": isinstance(v, int | float) and not isinstance(v, bool),
            "integer": isinstance(v, int) and not isinstance(v, bool)}[kind]


def _faults(kind: str) -> list[str]:
    return ["wrong type", "duplicate", *{"number": ["non-finite", "out of range"],
                                         "integer": ["non-finite", "out of range"],
                                         "string": ["too long", "control character"]}.get(kind, [])]


CASES = sorted({(command, field, fault) for command in VALID for field in [*VALID[command], *OPTIONAL]
                for fault in _faults(KINDS[field])} | {(command, None, "unknown") for command in VALID},
               key=str)
"""Every (command, field, fault) the issue names; hypothesis draws them evenly."""


@st.composite
def spoilt_value(draw, command, field, fault):
    """The raw JSON of ``field``'s value spoilt by ``fault``."""
    kind = KINDS[field]
    if fault == "wrong type":
        return json.dumps(draw(wrong_types(kind)))
    if fault == "non-finite":
        return draw(st.sampled_from(["1e999", "-1e999", "1E400", "-0.1e500"]))
    if fault == "out of range" and kind == "integer":
        return json.dumps(draw(st.one_of(st.integers(max_value=0), st.integers(min_value=COUNT_MAX + 1))))
    if fault == "out of range":
        lo, hi = ((FEEDING.min_portion_g, FEEDING.portion_g) if command == "feed" else (0.0, RATION_MAX_G))
        below = st.floats(max_value=lo, exclude_max=True, allow_nan=False, allow_infinity=False)
        above = st.floats(min_value=hi, exclude_min=True, allow_nan=False, allow_infinity=False)
        if command == "feed":
            below = below | st.floats(0, lo, exclude_max=True) | st.just(1e-300)
        huge = st.integers(min_value=10**309, max_value=10**400)
        return json.dumps(draw(st.one_of(below, above, huge)))
    cap = {"tank": 32, "to": 32, "source": SOURCE_MAX, "operator": OPERATOR_MAX, "reason": REASON_MAX}[field]
    if fault == "too long":
        return json.dumps(draw(st.text(st.sampled_from("ab é"), min_size=cap + 1, max_size=cap + 300)))
    text = draw(st.text(st.sampled_from("abT1"), max_size=cap - 1))
    at = draw(st.integers(0, len(text)))
    return json.dumps(text[:at] + draw(CONTROL) + text[at:])


@st.composite
def faulty(draw, command, field, fault):
    """(field that must be named, raw body): a valid payload of ``command`` with one field spoilt."""
    payload = draw(valid_payloads(command))
    fields = [*VALID[command], *OPTIONAL, *{"ack": ("kind", "all")}.get(command, ())]   # all it takes
    if fault == "unknown":
        field = draw(st.text(min_size=1, max_size=80).filter(lambda k: k not in fields))
        value = json.dumps(draw(json_values))
        named = printable(field, 64)
    elif fault == "duplicate":
        strategy = VALID[command].get(field, OPTIONAL.get(field))
        payload.setdefault(field, draw(strategy))
        value, named = json.dumps(draw(strategy)), field
    else:
        payload.pop(field, None)
        value, named = draw(spoilt_value(command, field, fault)), field
    pairs = [(k, json.dumps(v)) for k, v in payload.items()]
    pairs.insert(draw(st.integers(0, len(pairs))), (field, value))
    return named, as_json(pairs)


@pytest.mark.parametrize("command, field, fault", CASES, ids=["-".join(map(str, c)) for c in CASES])
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                 HealthCheck.too_slow])
@given(data=st.data())
def test_every_spoilt_field_is_refused_by_name_and_nothing_is_done(served, command, field, fault, data):
    farm, client = served
    named, body = data.draw(faulty(command, field, fault))
    before = farm.acted()
    reply = ask(client, command, body)
    assert reply["ok"] is False, (body, reply)
    assert reply["error"].startswith(f"{named}: "), (body, reply)
    assert len(reply["error"]) < 200 and not has_control(reply["error"])
    assert farm.acted() == before


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_valid_payloads_are_taken_exactly_as_sent(served, data):
    """The other half: strictness that refused everything would pass the test above."""
    farm, client = served
    command = data.draw(st.sampled_from(sorted(ORIGINAL)))
    payload = data.draw(valid_payloads(command))
    farm.robot.calls.clear()
    farm.published.clear()
    reply = ask(client, command, json.dumps(payload).encode())
    assert reply["ok"] is True, (payload, reply)
    expected = {"feed": [("on_demand", payload.get("tank"), float(payload.get("grams", 0)), "operator")],
                "manual": [("set_manual", payload.get("on"))], "reset": [("operator_reset",)],
                "ration": []}[command]
    assert farm.robot.calls == expected
    if command == "feed":
        assert reply["grams"] == round(payload["grams"], 1)
    if command == "ration":
        assert farm.published == [payload["tank"]]
        assert farm.rations.today(payload["tank"], farm.clock.now()).grams == payload["grams"]


@pytest.mark.parametrize("command, payload, error", [
    ("feed", {"tank": "T1", "grams": True}, "grams: must be a number, not a boolean"),
    ("feed", {"tank": "T1", "grams": "40"}, "grams: must be a number, not a string"),
    ("feed", {"tank": "T1", "grams": 1e-300}, "grams: less than feeding.min_portion_g (5 g)"),
    ("feed", {"tank": "T1", "grams": 61}, "grams: more than one portion, feeding.portion_g (60 g)"),
    ("ration", {"tank": "T1", "grams": True}, "grams: must be a number, not a boolean"),
    ("ration", {"tank": "T1", "grams": -1}, "grams: must be at least 0"),
    ("manual", {"on": "yes"}, "on: must be true or false, not a string"),
    ("feed", {"tank": "T1", "grams": 40, "reason": "x" * 50_000}, "reason: longer than 200 characters"),
    ("feed", {"tank": "T1", "grams": 40, "reason": "x" * 5_000_000},
     "payload of 5,000,041 bytes: a request is at most 65,536"),
    ("reset", {"reason": "ok\n2026-05-28T06:00:00Z WARNING fishfarm: all clear"},
     "reason: control characters (newline, carriage return, escape...) are not allowed"),
    ("feed", {"tank": "T9", "grams": 40}, "tank: no tank 'T9'"),
])
def test_the_issues_examples(served, command, payload, error):
    farm, client = served
    before = farm.acted()
    assert ask(client, command, json.dumps(payload).encode()) == {"ok": False, "error": error}
    assert farm.acted() == before


def test_duplicate_and_non_finite_on_the_wire(served):
    farm, client = served
    before = farm.acted()
    assert ask(client, "feed", b'{"tank": "T1", "grams": 40, "grams": 41}') == {
        "ok": False, "error": "grams: duplicate key"}
    assert ask(client, "ration", b'{"tank": "T1", "grams": 1e999}') == {
        "ok": False, "error": "grams: must be a finite number"}
    assert farm.acted() == before


def test_override_log_lines_cannot_be_forged(served, caplog):
    """The e-stop takes any payload, so what it logs is made one bounded line on the way out."""
    farm, client = served
    caplog.set_level(logging.WARNING, logger="fishfarm.override")
    forged = "x\n2026-05-28T06:00:00Z INFO    fishfarm: e-stop released\x1b[2J" + "y" * 100_000
    reply = ask(client, "estop", json.dumps({"operator": "ana\rbob", "reason": forged}).encode())
    assert reply == {"ok": True, "confirmed": True}
    assert ask(client, "feed", json.dumps({"tank": "T2", "grams": 30, "operator": "ana"}).encode())["ok"]
    lines = [r.getMessage() for r in caplog.records if r.name == "fishfarm.override"]
    assert len(lines) == 2 and lines[0].startswith("e-stop by ana\\rbob: x\\n2026")
    assert all(not has_control(line) and len(line) <= 1000 for line in lines)


def test_a_five_megabyte_reason_does_not_travel_in_status(served):
    farm, client = served
    huge = "why " * 1_250_000
    reply = ask(client, "estop", json.dumps({"operator": "ana", "reason": huge}).encode())
    assert reply == {"ok": True, "confirmed": True}
    replies = list(client.session.get("farm/demo/status", timeout=WAIT_S))
    alarms = json.loads(replies[0].ok.payload.to_bytes())["alarms"]
    # each alarm is its text (at most TEXT_MAX) and a dozen short fields: kilobytes, not megabytes
    assert len(replies) == 1 and len(replies[0].ok.payload.to_bytes()) < len(alarms) * (TEXT_MAX + 400)
    [alarm] = [a for a in alarms if a["source"] == "estop"]
    assert alarm["text"].startswith("emergency stop: operator ana: why why") and len(alarm["text"]) <= TEXT_MAX
    assert max(len(r["text"]) for r in farm.store.alarms()) <= TEXT_MAX


def test_a_ration_of_minus_zero_is_zero(served, caplog):
    farm, client = served
    with caplog.at_level(logging.WARNING, logger="fishfarm.override"):
        assert ask(client, "ration", b'{"tank": "T1", "grams": -0.0}') == {"ok": True}
    grams = farm.rations.today("T1", farm.clock.now()).grams
    assert grams == 0 and math.copysign(1.0, grams) == 1.0
    assert "ration T1 = 0 g" in caplog.text and "-0" not in caplog.text


def _audited(farm, n: int, before: int = 0) -> list[dict]:
    """The last ``n`` audit rows, once written (just after the reply, on the controller's loop):
    ``before`` rows were there already."""
    for _ in range(1000):
        rows = [dict(r) for r in farm.store.audit()]
        if len(rows) >= before + n:
            return rows[-n:]
        threading.Event().wait(0.01)
    raise AssertionError(f"{n} audit rows never written: {rows}")


def test_what_the_bus_refuses_before_any_handler_is_audited_too(served):
    farm, client = served
    before = len(farm.store.audit())
    launch = b'{"operator": "carol", "reason": "because"}'
    assert ask(client, "launch", launch)["error"].startswith("unknown command 'launch'")
    assert ask(client, "feed", b"\xff{oops")["error"] == "payload is not UTF-8"
    assert ask(client, "ration", b'{"tank": "T1", "grams": 1, "grams": 2}')["error"] == "grams: duplicate key"
    assert ask(client, "estop", b"\xff{oops") == {"ok": True, "confirmed": True}   # never refused
    rows = _audited(farm, 4, before)
    assert len(farm.store.audit()) == before + 4
    assert [(r["command"], r["payload"], r["ok"], r["result"][:20]) for r in rows] == [
        ("launch", '{"operator":"carol","reason":"because"}', 0, "unknown command 'lau"),
        ("feed", None, 0, "payload is not UTF-8"),
        ("ration", None, 0, "grams: duplicate key"), ("estop", None, 1, "ok")]
    # the operator the unknown command's payload claims is kept, as for any refused command
    assert rows[0]["operator"] == "carol"


def test_a_payload_readable_but_no_object_is_refused_and_audited_as_received(served):
    """README: the audit keeps "the payload as received ... none when unreadable"; JSON that is
    no object was readable, yet its row's payload was empty."""
    farm, client = served
    before = len(farm.store.audit())
    sent = [("feed", b'["T3"]'), ("reset", b' "T3" '), ("pause", b"null"), ("ration", b"42"), ("launch", b'["T3"]')]
    for command, body in sent:
        assert ask(client, command, body)["ok"] is False
    rows = _audited(farm, len(sent), before)
    assert [(r["command"], r["payload"], r["ok"]) for r in rows] == [
        ("feed", '["T3"]', 0), ("reset", '"T3"', 0), ("pause", "null", 0), ("ration", "42", 0), ("launch", '["T3"]', 0)]
    assert [r["result"] for r in rows[:4]] == [f"payload must be a JSON object, got {kind}"
                                               for kind in ("an array", "a string", "null", "a number")]


def test_an_estop_is_audited_with_what_it_was_sent_and_still_stops(served):
    """Empty or unreadable: none (it was audited as ``{}``, a payload nobody sent); JSON that is no
    object: as sent. Every one of them still trips the latches first and stops, never refused."""
    farm, client = served
    before, tripped, stops = len(farm.store.audit()), len(farm.tripped), len(farm.estops)
    sent = [b"", b"   ", b"{{{{", b"\xff", b'["T3"]', b"null", b'{"operator": "ana"}']
    for body in sent:
        assert ask(client, "estop", body) == {"ok": True, "confirmed": True}
    rows = _audited(farm, len(sent), before)
    assert [r["payload"] for r in rows] == [None, None, None, None, '["T3"]', "null", '{"operator":"ana"}']
    assert {(r["command"], r["ok"], r["result"]) for r in rows} == {("estop", 1, "ok")}
    urgent = farm.tripped[tripped:].count("operator e-stop")           # on the Zenoh thread, before parsing
    assert urgent == len(sent) and len(farm.estops) == stops + len(sent)
    assert farm.estops[-2:] == ["operator unknown", "operator ana"]


def test_a_handler_hands_the_authenticated_user_to_the_audit(tmp_path):
    """The bus (branch roles) calls each override handler with ``user=``: the audit names it, and
    keeps the name the payload claims beside it."""
    store = Store(tmp_path / "ledger.db")
    farm = Farm(store)
    overrides = Overrides(farm)
    handlers = {name: overrides._from_zenoh(name) for name in ("feed", "pause")}

    async def go():
        await handlers["feed"]({"tank": "T1", "grams": 20, "operator": "ana"}, user="op7")
        await handlers["pause"]({"tank": "T2"})
        await asyncio.sleep(0)
    asyncio.run(go())
    rows = [dict(r) for r in store.audit()]
    assert [(r["user"], r["operator"], r["command"], r["ok"]) for r in rows] == [
        ("op7", "ana", "feed", 1), (None, None, "pause", 1)]
    assert store.paused_tanks()["T2"]["who"] == "unknown (claimed)"
    store.close()


def test_the_history_queryable_serves_the_ledger_over_zenoh(served):
    farm, client = served
    farm.store.add_survey("T1", farm.clock.now() - 3600, "sparus_aurata", "h.json", [10.0, 11.0], [20.0, 24.0])
    [reply] = client.query("history/fish/T1?since=2h")
    assert reply["ok"] and [r[3] for r in reply["rows"]] == [20.0, 24.0]
    assert client.query("history/fish/T1?since=30m")[0]["rows"] == []
    [refused] = client.query("history/fish/T9")
    assert refused["ok"] is False and "no tank 'T9'" in refused["error"]
    assert client.query("history/fish/T1", {"since": "30m"})[0]["rows"] == []      # the range in the payload
    for garbage in (b"since=2h", b"[1, 2]", b"\xff\xfe"):     # a range it cannot read is refused, not ignored
        [reply] = client.session.get(client.key("history/fish/T1"), payload=garbage, timeout=2.0)
        answer = decode(reply.ok.payload)
        assert answer["ok"] is False and answer["error"], (garbage, answer)
    for key in ("history", "history/fish", "history/fish/T1/extra"):     # a level short or over: told so
        [refused] = client.query(key)
        assert refused["ok"] is False and "ask history/{" in refused["error"] and repr(key) in refused["error"]


def test_status_is_built_once_for_a_burst_of_queries_and_anew_after_an_override(served, monkeypatch):
    """400 status queries a second had each built and encoded the whole farm on the loop (a Modbus
    e-stop waited seconds behind them): a snapshot now answers every query for 0.1 s of wall, and an
    override renews it, so what it did shows in the very next status."""
    farm, client = served
    wall = [1e9]
    monkeypatch.setattr("controller.overrides._wall", lambda: wall[0])
    built, real = [], farm.status
    monkeypatch.setattr(farm, "status", lambda: built.append(1) or real())

    def status() -> dict:
        replies = [json.loads(r.ok.payload.to_bytes()) for r in client.session.get("farm/demo/status", timeout=WAIT_S)]
        assert len(replies) == 1
        return replies[0]
    first = [status() for _ in range(20)]
    assert len(built) == 1 and all(s == first[0] for s in first)
    wall[0] += 0.1
    status()
    assert len(built) == 2
    assert ask(client, "ack", json.dumps({"source": "pump", "kind": "power", "operator": "ana"}).encode())["ok"]
    after = status()
    assert len(built) == 3 and after != first[0]


def test_a_status_asked_while_an_override_waits_is_not_the_one_after_its_reply(served, monkeypatch):
    """A reset waits for the cleaner's thrusters to confirm their latch released; a status another
    client asked meanwhile was kept as the fresh snapshot, and the reset's own client, told ok, read
    the cleaner in ``estop`` for up to 0.1 s more. An e-stop tripped from another thread (the Modbus
    coil, Zenoh's own thread) makes the snapshot stale at once too."""
    farm, client = served
    monkeypatch.setattr("controller.overrides._wall", lambda: 2e9)    # fresh for ever, unless renewed
    entered, release = threading.Event(), threading.Event()

    class Cleaner:
        state = "estop"

        async def operator_reset(self):
            entered.set()
            while not release.is_set():
                await asyncio.sleep(0.01)
            self.state = "docked"

    class Lane:
        tripped = False

        def confirming(self, _s):
            return False
    monkeypatch.setattr(farm, "cleaner", Cleaner(), raising=False)
    monkeypatch.setattr(farm, "lane", Lane(), raising=False)
    real = farm.status
    monkeypatch.setattr(farm, "status", lambda: {**real(), "cleaner": farm.cleaner.state,
                                                 "tripped": farm.lane.tripped})

    def status() -> dict:
        return json.loads(next(iter(client.session.get("farm/demo/status", timeout=WAIT_S))).ok.payload.to_bytes())
    replies = []
    asker = threading.Thread(target=lambda: replies.append(ask(client, "reset", b'{"operator": "ana"}')))
    asker.start()
    assert entered.wait(WAIT_S)
    assert status()["cleaner"] == "estop"                  # another client, while the reset waits
    release.set()
    asker.join(WAIT_S)
    assert replies == [{"ok": True}] and status()["cleaner"] == "docked"
    farm.lane.tripped = True                              # a trip on another thread: no override here
    assert status()["tripped"] is True
