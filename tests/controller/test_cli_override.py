"""``fishfarm override`` / ``fishfarm status``: the real console script, in a subprocess, against a
queryable served by this test over Zenoh on a free loopback port."""
from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from controller.bus import Bus
from controller.cli.override_cmd import parse_args, render_status
from controller.config import BusConfig
from controller.errors import BadInput
from hil_tests.ports import free_port

FISHFARM = str(Path(sys.executable).with_name("fishfarm"))
# the shape controller.app.Controller.status() answers with
SNAPSHOT = {
    "t": "2024-05-01T06:00:00Z", "site": "demo",
    "feeder": {"t": "2024-05-01T06:00:00Z", "state": "dispensing", "position_m": 3.0, "hopper_g": 5200.0},
    "tanks": {
        "T1": {"demand": True, "demand_t": "2024-05-01T05:59:40Z", "fed_g": 120.0, "ration_g": 420.0,
               "pellet_mm": 2.0},
        "T2": {"demand": False, "demand_t": None, "fed_g": 380.0, "ration_g": 380.0, "pellet_mm": 3.0}},
    "alarms": [{"source": "sensor/T2-b", "severity": "warning", "text": "tank T2: sensor T2-b stuck",
                "t": "2024-05-01T05:50:00Z"}],
}
TABLE = """site demo  2024-05-01T06:00:00Z
tank  demand  fed/ration g  pellet
T1    yes     120/420       2.0 mm
T2    -       380/380       3.0 mm
feeder: dispensing (position_m 3.0, hopper_g 5200)
ALARM warning sensor/T2-b: tank T2: sensor T2-b stuck"""


@pytest.fixture(scope="module")
def controller():
    """A stand-in controller: real Bus, real queryables; records what each command received."""
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = Bus(BusConfig(mode="peer", listen=[endpoint]), "demo", loop=loop)
    received: list[tuple[str, dict]] = []

    async def estop(payload):
        received.append(("estop", payload))
        return {"ok": True}

    async def feed(payload):
        received.append(("feed", payload))
        return {"ok": False, "error": "feeder is in manual"}

    async def mortality(payload):              # carried out, its answer later than the tool waits
        received.append(("mortality", payload))
        await asyncio.sleep(1.5)
        return {"ok": True, "stock": {"T3": 995}}

    async def status(payload):
        return SNAPSHOT
    bus.overrides({"estop": estop, "feed": feed, "mortality": mortality})
    bus.queryable("status", status, lenient=True)
    yield endpoint, received
    bus.close()
    loop.call_soon_threadsafe(loop.stop)
    thread.join(5)


def fishfarm(*args, user="tester"):
    env = {**os.environ, "USER": user}
    return subprocess.run([FISHFARM, *args], capture_output=True, text=True, env=env, timeout=60)


def one_line_error(proc) -> str:
    assert proc.stdout == ""
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr
    return proc.stderr


def test_estop_with_no_args_is_accepted(controller):
    endpoint, received = controller
    received.clear()
    proc = fishfarm("override", "estop", "--connect", endpoint)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == {"ok": True}
    assert received == [("estop", {"operator": "tester"})]


@pytest.mark.parametrize("extra, kept", [
    (["now"], {}),                                             # not key=value
    (["tank"], {}),
    (["operator=bob", "now", "tank=T1"], {"tank": "T1"}),      # reserved, unreadable, fine
    (["tank=T1", "tank=T2"], {"tank": "T1"}),                  # given twice
    (["--now", "-f"], {}),                                     # no such options
    (["--reason", "a", "--reason", "b"], {"reason": "b"}),     # an option given twice
    (["--reason", "a", "--reason", "b", "--site", "demo"], {"reason": "b"}),
])
def test_an_estop_with_words_it_cannot_read_is_sent_all_the_same(controller, extra, kept):
    """DESIGN.md: an emergency action is never refused for a missing detail. `fishfarm override
    estop now` exited 2 and sent nothing: what cannot be read is said and left out."""
    endpoint, received = controller
    received.clear()
    proc = fishfarm("override", "estop", *extra, "--connect", endpoint)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == {"ok": True}
    assert received == [("estop", {"operator": "tester", **kept})]
    readable = {"tank=T1", "a", "b", "--reason", "--site", "demo"}
    assert all(f"{w}: " in proc.stderr and "the e-stop is sent all the same" in proc.stderr
               for w in extra if w not in readable), proc.stderr
    # README: an option given twice is said too (the last was sent without a word)
    assert ("--reason given more than once: the last is sent" in proc.stderr) == (extra.count("--reason") > 1)
    assert ("tank given more than once (the first is sent)" in proc.stderr) == (extra.count("tank=T2") > 0)


def test_an_option_no_command_has_is_refused_for_every_command_but_estop(controller):
    endpoint, received = controller
    received.clear()
    proc = fishfarm("override", "feed", "tank=T1", "grams=10", "--now", "--connect", endpoint)
    assert proc.returncode == 2 and "--now: no such option" in one_line_error(proc) and received == []


def test_refusal_exits_1_and_args_become_typed_fields(controller):
    endpoint, received = controller
    received.clear()
    proc = fishfarm("override", "feed", "tank=T3", "grams=40", "rate=12.5", "--connect", endpoint,
                    "--operator", "ana", "--reason", "fish look hungry")
    assert proc.returncode == 1, proc.stderr
    assert json.loads(proc.stdout) == {"ok": False, "error": "feeder is in manual"}
    [(command, payload)] = received
    assert re.fullmatch(r"[0-9a-f]{32}", payload.pop("request"))     # an id to send it again by
    assert (command, payload) == ("feed", {"operator": "ana", "reason": "fish look hungry",
                                           "tank": "T3", "grams": 40, "rate": 12.5})


def test_an_override_without_a_reply_names_the_id_to_send_it_again_by(controller):
    """The controller may have carried it out and its reply been lost: sending it again under the
    id named is done once (controller.override_requests)."""
    endpoint, received = controller
    received.clear()
    proc = fishfarm("override", "feed", "tank=T3", "grams=40", "--connect", endpoint, "--site", "elsewhere",
                    "--timeout", "0.5")
    assert proc.returncode == 2
    request = re.search(r"add request=([0-9a-f]{32}) to send it again without doing it twice$",
                        one_line_error(proc).strip())
    assert request
    received.clear()
    proc = fishfarm("override", "feed", "tank=T3", "grams=40", f"request={request[1]}", "--connect", endpoint)
    assert received[0][1]["request"] == request[1]                  # as given, a string
    proc = fishfarm("override", "feed", "tank=T3", "request=12", "--connect", endpoint)
    assert received[1][1]["request"] == "12"


def test_unknown_command_is_refused_by_the_controller(controller):
    endpoint, _ = controller
    proc = fishfarm("override", "launch", "--connect", endpoint)
    assert proc.returncode == 1
    assert "unknown command 'launch'" in json.loads(proc.stdout)["error"]


@pytest.mark.parametrize("args, names", [
    (["override", "feed", "tank"], "tank"),
    (["override", "feed", "tank=T1", "tank=T2"], "given twice"),
    (["override", "feed", "operator=bob"], "--operator"),
    (["override", "Feed/*"], "COMMAND"),
    (["override", "estop", "--connect", "127.0.0.1:7447"], "--connect"),
    (["override", "estop", "--connect", "tcp/127.0.0.1:99999"], "--connect: tcp/127.0.0.1:99999: port 99999 is "
                                                                 "outside 1..65535"),
    (["status", "--connect", "tcp/127.0.0.1:0"], "--connect: tcp/127.0.0.1:0: port 0"),
    (["status", "--site", "de mo"], "--site"),
])
def test_bad_input_exits_2_with_one_line(controller, args, names):
    endpoint, received = controller
    received.clear()
    proc = fishfarm(*args, *([] if "--connect" in args else ["--connect", endpoint]))
    assert proc.returncode == 2
    assert names in one_line_error(proc)
    assert received == []


def test_an_answer_later_than_the_timeout_is_no_reply_not_a_refusal(controller):
    """Zenoh ends a get past its timeout with an error reply ("Timeout"): it was printed as the
    controller's refusal (exit 1), so the operator sent a mortality it had booked again without its
    id (twice booked), and an e-stop it had latched was read as not done."""
    endpoint, received = controller
    received.clear()
    proc = fishfarm("override", "mortality", "tank=T3", "count=5", "--connect", endpoint, "--timeout", "0.5")
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    said = one_line_error(proc)
    assert "no reply within 0.5 s" in said and "add request=" in said and "Timeout" not in said
    assert [c for c, _ in received] == ["mortality"]


def test_nobody_listening_exits_2_saying_so():
    port = free_port()
    proc = fishfarm("override", "estop", "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "0.5")
    assert proc.returncode == 2
    assert f"could not connect to tcp/127.0.0.1:{port}" in one_line_error(proc)


def test_a_listener_that_never_answers_is_not_said_to_have_refused():
    """A SIGSTOPped controller: the kernel takes the connection, nothing answers. It was reported as
    'refused the session (does it require --user/--password?)' on a farm with no logins."""
    import socket
    with socket.socket() as frozen:
        frozen.bind(("127.0.0.1", 0))
        frozen.listen()
        port = frozen.getsockname()[1]
        proc = fishfarm("override", "estop", "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "0.5")
    assert proc.returncode == 2
    assert "nothing there answers (a frozen or overloaded controller)" in one_line_error(proc)


def test_wrong_site_gets_no_reply_exit_2(controller):
    endpoint, received = controller
    received.clear()
    proc = fishfarm("override", "estop", "--connect", endpoint, "--site", "elsewhere", "--timeout", "0.5")
    assert proc.returncode == 2
    assert "farm/elsewhere/override/estop: no reply" in one_line_error(proc)
    assert received == []


def test_status_json_and_table(controller):
    endpoint, _ = controller
    proc = fishfarm("status", "--json", "--connect", endpoint)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == SNAPSHOT
    proc = fishfarm("status", "--connect", endpoint)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == TABLE + "\n"


def test_parse_args_types():
    assert parse_args(["tank=T1", "grams=40", "g2=4.5", "n=-3", "e=1e3", "x=1_000", "y=nan", "z="]) == {
        "tank": "T1", "grams": 40, "g2": 4.5, "n": -3, "e": 1000.0, "x": "1_000", "y": "nan", "z": ""}
    assert parse_args(["reason_code=a=b"]) == {"reason_code": "a=b"}
    assert parse_args(["on=true", "off=false", "yes=yes", "t=True", "tank=12", "grams=12"]) == {
        "on": True, "off": False, "yes": "yes", "t": "True", "tank": "12", "grams": 12}
    for bad in (["=3"], ["1x=3"], ["a b=3"], ["reason=x"]):
        with pytest.raises(BadInput):
            parse_args(bad)


def test_status_table_reads_the_snapshot():
    assert render_status(SNAPSHOT) == TABLE
    # the hub's line health shows once anything is wrong with it
    clean = {"device": "contacts", "unknown_sensors": [], "malformed": 0, "lost": 0}
    assert render_status({**SNAPSHOT, "contacts": clean}) == TABLE
    noisy = {**clean, "malformed": 12, "lost": 3, "unknown_sensors": ["T9-a"]}
    assert "contacts: 12 lines rejected, 3 missing; unknown sensors T9-a" in render_status(
        {**SNAPSHOT, "contacts": noisy})
    # a snapshot it does not fully know still renders, with dashes
    sparse = render_status({"tanks": {"T9": {"fed_g": 3}}, "feeder": "?"})
    assert "T9" in sparse and "3/-" in sparse
    # integers whole, a small share not rounded away (it said coverage 0.0, state_code 1.0)
    cleaner = render_status({"cleaner": {"state": "localising", "coverage": 0.0012, "path_index": 0, "state_code": 1}})
    assert "cleaner: localising (coverage 0.0012, path_index 0, state_code 1)" in cleaner


def test_status_table_escapes_what_it_prints():
    hostile = {**SNAPSHOT, "alarms": [{"source": "x\x1b[2J", "severity": "warning", "text": "a\nFORGED " + "y" * 5000}]}
    table = render_status(hostile)
    assert "\x1b" not in table and "\nFORGED" not in table and len(table.splitlines()[-1]) <= 1000


def test_booleans_and_tank_ids_travel_typed(controller):
    endpoint, received = controller
    received.clear()
    proc = fishfarm("override", "feed", "tank=12", "grams=40", "on=true", "off=false", "word=yes",
                    "--connect", endpoint)
    assert proc.returncode == 1, proc.stderr
    received[0][1].pop("request")
    assert received == [("feed", {"operator": "tester", "tank": "12", "grams": 40, "on": True, "off": False,
                                  "word": "yes"})]


def test_status_table_shows_the_survey_under_way():
    snap = {**SNAPSHOT, "survey": {"current": {"tank": "T3", "why": "operator", "captured": 12, "pairs": 40,
                                               "fish": 9, "visits": 3}, "asked": ["T5"]}}
    assert "survey: T3 (operator) 12/40 pairs, 9 fish, 3 visits; asked: T5" in render_status(snap).splitlines()
    idle = render_status({**SNAPSHOT, "survey": {"current": None, "asked": []}, "alarms": []})
    assert idle.splitlines()[-1] == "survey: none under way"
    assert "survey" not in render_status({**SNAPSHOT, "alarms": []})     # no camera: no line
