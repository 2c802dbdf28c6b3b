"""config/zenoh/*.json5 load in eclipse-zenoh 1.10.2, and the deployment config's
authentication and access control behave: the controller runs as the router from
deploy.json5 (moved to a free loopback port), tools connect as clients with the example
credentials of config/zenoh/credentials.txt."""
from __future__ import annotations

import asyncio
import json
import os
import queue
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from controller.bus import Bus, BusUnreachable
from controller.config import BusConfig

ROOT = Path(__file__).resolve().parents[2]
ZDIR = ROOT / "config" / "zenoh"
FISHFARM = str(Path(sys.executable).with_name("fishfarm"))
WAIT_S = 10.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def credentials() -> dict[str, str]:
    lines = (ZDIR / "credentials.txt").read_text().splitlines()
    return dict(line.split(":", 1) for line in lines)


def test_both_configs_load_with_multicast_off():
    demo = zenoh.Config.from_file(ZDIR / "demo.json5")
    assert json.loads(demo.get_json("mode")) == "peer"
    assert json.loads(demo.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    deploy = zenoh.Config.from_file(ZDIR / "deploy.json5")
    assert json.loads(deploy.get_json("mode")) == "router"
    for cfg in (demo, deploy):
        assert cfg.get_json("scouting/multicast/enabled") == "false"
    acl = json.loads(deploy.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    dictionary = json.loads(deploy.get_json("transport/auth/usrpwd/dictionary_file"))
    assert (ROOT / dictionary).resolve() == (ZDIR / "credentials.txt").resolve()
    users = {u for s in acl["subjects"] for u in s["usernames"]}
    assert users <= set(credentials())  # every role has an example login


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    """The controller, as a router on deploy.json5, serving overrides and status, subscribed to farm/**."""
    text = (ZDIR / "deploy.json5").read_text()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    for old, new in [('"tcp/0.0.0.0:7447"', json.dumps(endpoint)),
                     ('"config/zenoh/credentials.txt"', json.dumps(str(ZDIR / "credentials.txt")))]:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path_factory.mktemp("zenoh") / "deploy.json5"
    path.write_text(text)

    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    bus = Bus(BusConfig(config=str(path)), "demo", loop=loop)
    calls: list[str] = []
    heard: queue.Queue = queue.Queue()

    async def estop(payload):
        calls.append(payload.get("operator", "?"))
        return {"ok": True}

    async def status(payload):
        return {"site": "demo", "tanks": []}

    async def listener(suffix, payload):
        heard.put((suffix, payload))
    bus.overrides({"estop": estop})
    bus.queryable("status", status)
    bus.subscribe("**", listener)
    yield endpoint, bus, calls, heard
    bus.close()
    loop.call_soon_threadsafe(loop.stop)
    thread.join(5)


def login(endpoint, user, **kw) -> Bus:
    return Bus.client(endpoint, user=user, password=credentials()[user], timeout_s=WAIT_S, **kw)


def test_operator_may_call_overrides_and_status(farm):
    endpoint, _, calls, _ = farm
    calls.clear()
    with login(endpoint, "operator") as op:
        assert op.query("override/estop", {"operator": "ana"}) == [{"ok": True}]
        assert op.query("status") == [{"site": "demo", "tanks": []}]
    assert calls == ["ana"]


def test_viewer_gets_nothing_from_overrides_or_status(farm):
    endpoint, _, calls, _ = farm
    calls.clear()
    with login(endpoint, "viewer") as viewer:
        assert viewer.neighbours()  # admitted to the network ...
        assert viewer.query("override/estop", {"operator": "mallory"}) == []  # ... but denied
        assert viewer.query("status") == []
    assert calls == []


def _wait_probe(publisher: Bus, suffix: str, arrived: threading.Event) -> None:
    """Publish probes until one arrives (a fresh route drops its first puts, see test_bus)."""
    deadline = time.monotonic() + WAIT_S
    while not arrived.wait(0.01):
        assert time.monotonic() < deadline, "nothing arrives"
        publisher.publish(suffix, {"probe": True})


def test_viewer_hears_publications_operator_does_not(farm):
    endpoint, bus, _, _ = farm
    loop = bus._loop
    got = {"viewer": queue.Queue(), "operator": queue.Queue()}
    probed = threading.Event()

    def recorder(who):
        async def listener(suffix, payload):
            if who == "viewer" and payload.get("probe"):
                probed.set()
            got[who].put((suffix, payload))
        return listener
    with login(endpoint, "viewer", loop=loop) as viewer, login(endpoint, "operator", loop=loop) as op:
        viewer.subscribe("**", recorder("viewer"))
        op.subscribe("**", recorder("operator"))
        _wait_probe(bus, "tank/T1/feed", probed)
        bus.publish("tank/T1/feed", {"grams": 40.0, "phase": "done", "id": "f1"}, reliable=True)
        while (item := got["viewer"].get(timeout=WAIT_S))[1].get("probe"):
            pass
        assert item == ("tank/T1/feed", {"grams": 40.0, "phase": "done", "id": "f1"})
        # the viewer has heard everything, probes included; the operator, published to by the same
        # router over the same kind of link, has heard none of it
        assert got["operator"].empty()


def test_only_the_controller_user_may_publish(farm):
    endpoint, bus, _, heard = farm
    while not heard.empty():  # the controller's own publications from other tests
        heard.get()
    with login(endpoint, "viewer") as viewer, login(endpoint, "controller") as peer:
        viewer.publish("tank/T1/demand", {"forged": True})
        assert viewer.query("status") == []  # a round trip behind the put: the router has handled it
        seen = []
        deadline = time.monotonic() + WAIT_S
        while ("tank/T2/demand", {"rate_hz": 0.5}) not in seen:
            assert time.monotonic() < deadline, "the controller user's publications never arrive"
            peer.publish("tank/T2/demand", {"rate_hz": 0.5})
            try:
                seen.append(heard.get(timeout=0.05))
            except queue.Empty:
                pass
        assert ("tank/T1/demand", {"forged": True}) not in seen


def test_wrong_or_missing_password_is_refused(farm):
    endpoint, _, calls, _ = farm
    with pytest.raises(BusUnreachable, match="authentication failed for user 'operator'"):
        Bus.client(endpoint, user="operator", password="not-the-password", timeout_s=1.0)
    with pytest.raises(BusUnreachable, match="require --user/--password"):
        Bus.client(endpoint, timeout_s=1.0)
    with pytest.raises(BusUnreachable, match="authentication failed"):  # a peer is not refused, only alone
        Bus.client(endpoint, user="operator", password="nope", timeout_s=0.5, mode="peer")
    calls.clear()
    proc = subprocess.run([FISHFARM, "override", "estop", "--connect", endpoint, "--user", "operator",
                           "--password", "wrong"], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "USER": "tester"})
    assert proc.returncode == 2 and proc.stdout == ""
    assert "authentication failed" in proc.stderr and proc.stderr.count("\n") == 1
    assert calls == []


def test_cli_operator_login_works(farm):
    endpoint, _, calls, _ = farm
    calls.clear()
    proc = subprocess.run([FISHFARM, "override", "estop", "--connect", endpoint, "--user", "operator",
                           "--password", credentials()["operator"]], capture_output=True, text=True,
                          timeout=60, env={**os.environ, "USER": "tester"})
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == {"ok": True} and calls == ["tester"]
