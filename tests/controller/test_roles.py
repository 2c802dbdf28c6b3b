"""Roles and identity on the deployed controller's Zenoh router (config/zenoh/deploy.json5, real
Zenoh over loopback, credentials from `fishfarm credentials`): what each role may do, that the
handler learns the authenticated user, that impostors holding another role's credentials can
neither serve status nor publish, and what a refused command-line user sees."""
from __future__ import annotations

import asyncio
import functools
import json
import os
import queue
import stat
import subprocess
import threading
import time

import pytest
import zenoh

from controller.bus import Bus, BusUnreachable, _with_user
from controller.cli import main as fishfarm_main
from controller.cli.credentials_cmd import USERS, read
from controller.config import BusConfig
from controller.errors import BadInput
from controller.identity import bind_identities, identities_bound
from tests.controller.zenoh_farm import FISHFARM, ROLE_OF, WAIT_S, ZDIR, free_port, start_farm, wait_probe

# who may send what, from the roles' words in README (deploy.json5 is what is under test)
# (e-stop "is open to every authenticated login": the vision workers' too)
# (and the controller's own login used remotely: its e-stop went unanswered, an outside tester)
ALLOWED = {"viewer": {"estop"}, "operator": {"estop", "feed", "pause", "reset"},
           "engineer": {"estop", "feed", "pause", "reset", "ration", "settle"}, "worker": {"estop"},
           "controller": {"estop"}, None: set()}
COMMANDS = ("estop", "feed", "pause", "reset", "ration", "settle")


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    farm, stop = start_farm(tmp_path_factory.mktemp("roles"))
    yield farm
    stop()


def _reply(command: str) -> list[dict]:
    return [{"ok": True, "command": command}]


# ---------------------------------------------------------------- what Zenoh gives a queryable

def test_zenoh_does_not_tell_a_queryable_who_asked(tmp_path):
    """The measurement behind controller/identity.py (eclipse-zenoh 1.10.2): a router with
    user/password logins learns, for a query, neither the user (source_info is None) nor, in its
    admin space or its links, the user name of any client session."""
    creds = tmp_path / "credentials.txt"
    creds.write_text("ana:secret-ana\n")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = zenoh.Config()
    for key, value in {"mode": "router", "listen/endpoints": [endpoint], "scouting/multicast/enabled": False,
                       "scouting/gossip/enabled": False, "adminspace/enabled": True,
                       "transport/auth/usrpwd/dictionary_file": str(creds)}.items():
        cfg.insert_json5(key, json.dumps(value))
    seen = []
    with zenoh.open(cfg) as router:
        def on_query(query):
            seen.append((query.source_info, query.attachment))
            query.reply(query.key_expr, b"{}")
            query.drop()
        router.declare_queryable("farm/demo/override/feed", on_query)
        with Bus.client(endpoint, user="ana", password="secret-ana", timeout_s=WAIT_S) as ana:
            assert ana.query("override/feed", {}) == [{}]
            admin = [r.ok.payload.to_bytes().decode("utf-8", "replace") for r in router.get("@/**", timeout=2)
                     if r.ok is not None]
            links = router.info.links()
        assert seen == [(None, None)]
        assert admin and not any("ana" in text for text in admin)
        assert links and all(link.auth_identifier is None for link in links)


# ---------------------------------------------------------------- identity

def test_the_handler_learns_the_authenticated_user(farm):
    farm.calls.clear()
    with farm.login("ana") as ana, farm.login("erin") as erin:
        # the payload claims somebody else: the claim is kept, the login is what the bus vouches for
        assert ana.query("override/feed/by/ana", {"operator": "mallory"}) == _reply("feed")
        assert erin.query("override/ration/by/erin", {"operator": "erin"}) == _reply("ration")
        assert ana.query("override/feed", {"operator": "ana"}) == _reply("feed")       # contract key
        assert ana.query("override/reset/by/ana", {"operator": "ana"}) == _reply("reset")  # old handler
    assert farm.calls == [("feed", "mallory", "ana"), ("ration", "erin", "erin"), ("feed", "ana", None),
                          ("reset", "ana", "old-style")]


@pytest.mark.parametrize("login", ["ana", "erin", "operator", "engineer", "viewer", "controller"])
def test_nobody_poses_as_another(farm, login):
    farm.calls.clear()
    with farm.login(login) as who:
        for other in ("ana", "erin", "operator", "engineer", "viewer", "controller", "nobody"):
            if other == login:
                continue
            for command in ("estop", "feed", "ration"):
                assert who.query(f"override/{command}/by/{other}", {}) == [], (login, other, command)
        assert who.query("override/feed/by/*", {}) == []   # a wildcard: nobody answers it
    assert farm.calls == []


# ---------------------------------------------------------------- roles

@pytest.mark.parametrize("login", ["viewer", "vic", "operator", "ana", "engineer", "erin", "controller", "worker"])
def test_each_role_may_send_what_it_is_allowed_and_nothing_else(farm, login):
    allowed = ALLOWED[ROLE_OF[login]]
    farm.calls.clear()
    with farm.login(login) as who:
        for command in COMMANDS:
            for key in (f"override/{command}", f"override/{command}/by/{login}"):
                assert who.query(key, {}) == (_reply(command) if command in allowed else []), (login, key)
        assert who.query("status") == ([{"site": "demo", "tanks": [], "by": "controller"}]
                                       if ROLE_OF[login] not in (None, "worker", "controller") else [])
    assert sorted(c for c, _, _ in farm.calls) == sorted(2 * list(allowed))


def test_the_unauthenticated_cannot_even_estop(farm):
    farm.calls.clear()
    with pytest.raises(BusUnreachable, match="requires --user/--password"):
        Bus.client(farm.endpoint, timeout_s=1.0)
    with pytest.raises(BusUnreachable):
        Bus.client(farm.endpoint, timeout_s=1.0, mode="peer")
    assert farm.calls == []


# ---------------------------------------------------------------- impostors

@pytest.mark.parametrize("stolen", ["viewer", "operator", "engineer", "controller"])
def test_an_impostor_neither_serves_status_nor_publishes_alarms(farm, stolen):
    """A second 'controller' started with stolen credentials (any user but the controller process
    itself, which is the router): its queryables never get a query, its alarms reach nobody; what
    it can still do is what its role allows (an operator's overrides)."""
    loop = farm.bus._loop
    faked = []

    async def fake(payload, *, user=None):
        faked.append(payload)
        return {"ok": True, "site": "demo", "tanks": ["forged"], "by": "impostor"}
    got: queue.Queue = queue.Queue()
    probed = threading.Event()

    async def viewer_hears(suffix, payload):
        if payload.get("probe"):
            probed.set()
        got.put((suffix, payload))
    with farm.login(stolen, loop=loop) as impostor, farm.login("vic", loop=loop) as vic, \
            farm.login("ana") as ana:
        impostor.queryable("status", fake)
        impostor.overrides({"estop": fake, "feed": fake, "ration": fake})
        vic.subscribe("alarm/**", viewer_hears)
        wait_probe(farm.bus, "alarm/probe", probed)
        farm.drain()
        for _ in range(20):
            impostor.publish("alarm/feeder", {"t": "x", "severity": "critical", "text": "forged", "active": True})
            impostor.publish("alarm/estop", {"forged": True}, reliable=True)
        assert impostor.flush()
        # a round trip behind the puts on the same link (a key the impostor does not serve itself,
        # or it would answer itself): the router has had them
        impostor.query("feeder/state")
        farm.bus.publish("alarm/feeder", {"t": "y", "severity": "info", "text": "real", "active": False},
                         reliable=True)
        while (item := got.get(timeout=WAIT_S))[1].get("probe"):
            pass
        assert item == ("alarm/feeder", {"t": "y", "severity": "info", "text": "real", "active": False})
        # the operator asking gets the controller alone, status and overrides alike
        assert ana.query("status") == [{"site": "demo", "tanks": [], "by": "controller"}]
        assert ana.query("override/feed/by/ana", {}) == _reply("feed")
        assert ana.query("override/estop", {}) == _reply("estop")
    assert faked == []
    assert all(payload.get("text") != "forged" and not payload.get("forged")
               for _, payload in list(farm.heard.queue))   # the controller's own subscriber too


# ---------------------------------------------------------------- what a refused user sees

def _fishfarm(*args, timeout_s=2.0):
    started = time.monotonic()
    proc = subprocess.run([FISHFARM, *args, "--timeout", str(timeout_s)], capture_output=True, text=True,
                          timeout=60, env={**os.environ, "USER": "tester"})
    return proc, time.monotonic() - started


def test_a_refused_command_line_user_reads_one_line_and_exit_2(farm):
    farm.calls.clear()
    login = ["--connect", farm.endpoint, "--user", "viewer", "--password", farm.passwords["viewer"]]
    proc, took = _fishfarm("override", "feed", "tank=T1", "grams=5", *login)
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    assert proc.stderr.startswith("fishfarm: farm/demo/override/feed/by/viewer: no reply within 2 s while status "
                                  "answers: user 'viewer' may not send this (access control)")
    assert proc.stderr.count("\n") == 1 and "add request=" in proc.stderr   # or it came too late: the id
    assert took < 30   # bounded by --timeout, not a hang (process start-up included)
    proc, _ = _fishfarm("status", "--connect", farm.endpoint)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "requires --user/--password" in proc.stderr
    proc, _ = _fishfarm("override", "estop", *login)
    assert proc.returncode == 0 and json.loads(proc.stdout) == _reply("estop")[0]
    ana = ["--connect", farm.endpoint, "--user", "ana", "--password", farm.passwords["ana"]]
    proc, _ = _fishfarm("override", "feed", "tank=T1", "grams=5", *ana)
    assert proc.returncode == 0, proc.stderr
    assert farm.calls == [("estop", "tester", "viewer"), ("feed", "tester", "ana")]


# ---------------------------------------------------------------- the ACL binding and credentials

def _acl(key: str = "farm/*/override/feed", users=("ana",)) -> dict:
    return {"enabled": True, "default_permission": "deny",
            "rules": [{"id": "ask", "permission": "allow", "flows": ["ingress"], "messages": ["query"],
                       "key_exprs": [key, "farm/*/status"]}],
            "subjects": [{"id": "ops", "usernames": list(users)}],
            "policies": [{"id": "p", "rules": ["ask"], "subjects": ["ops"]}]}


def test_identity_rules_are_each_users_own():
    bound = bind_identities(_acl(users=("ana", "bob")))
    own = {r["id"]: r["key_exprs"] for r in bound["rules"] if r["id"] != "ask"}
    assert own == {"ask as ana (ops)": ["farm/*/override/feed/by/ana"],
                   "ask as bob (ops)": ["farm/*/override/feed/by/bob"]}
    subjects = {s["id"]: s["usernames"] for s in bound["subjects"]}
    policies = {p["id"]: (p["rules"], p["subjects"]) for p in bound["policies"]}
    for user in ("ana", "bob"):
        tag = f"p as {user} (ops)"
        assert subjects[tag] == [user] and policies[tag] == ([f"ask as {user} (ops)"], [tag])
    assert bind_identities({"enabled": False, "rules": "left alone"}) == {"enabled": False, "rules": "left alone"}


@pytest.mark.parametrize("key", ["farm/*/override/**", "farm/**", "**", "farm/demo/override/feed/by/ana",
                                 "farm/*/override/*/by/*"])
def test_a_rule_that_would_let_users_pose_as_others_is_refused(key):
    with pytest.raises(BadInput, match="pose as another user"):
        bind_identities(_acl(key))


def test_only_a_default_deny_acl_vouches_for_users():
    assert identities_bound(bind_identities(_acl()))
    assert not identities_bound(bind_identities({**_acl(), "default_permission": "allow"}))
    assert not identities_bound(bind_identities({**_acl(), "enabled": False}))
    assert not identities_bound({})    # the demo: no access control


def test_a_user_name_that_is_no_key_chunk_is_refused():
    with pytest.raises(BadInput, match="subjects.ops"):
        bind_identities(_acl(users=("ana/x",)))


def test_credentials_are_random_private_and_never_overwritten(tmp_path):
    out = tmp_path / "zenoh" / "credentials.txt"
    assert fishfarm_main(["credentials", "--out", str(out)]) == 0
    first = read(out)
    assert tuple(first) == USERS
    assert stat.S_IMODE(out.stat().st_mode) == 0o600
    assert len(set(first.values())) == len(USERS) and all(len(p) >= 24 and p[0] != "-" for p in first.values())
    proc = subprocess.run([FISHFARM, "credentials", "--out", str(out)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "exists already" in proc.stderr
    assert read(out) == first
    assert fishfarm_main(["credentials", "--out", str(out), "--force"]) == 0
    assert not set(read(out).values()) & set(first.values())
    proc = subprocess.run([FISHFARM, "credentials", "--out", str(out), "--add", "ana"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout == f"ana:{read(out)['ana']}\n"
    assert fishfarm_main(["credentials", "--out", str(out), "--add", "ana"]) == 2
    assert fishfarm_main(["credentials", "--out", str(out), "--add", "ana:x"]) == 2
    proc = subprocess.run([FISHFARM, "credentials", "--out", str(out), "--add", "x\ny"], capture_output=True,
                          text=True, timeout=60)         # the name echoed raw: a refusal of two lines
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "'x\\ny'" in proc.stderr, proc.stderr
    before = out.read_text()
    proc = subprocess.run([FISHFARM, "credentials", "--out", str(out), "--add", "bob", "--add", "bob"],
                          capture_output=True, text=True, timeout=60)     # "user exists already": none did
    assert proc.returncode == 2 and proc.stderr == "fishfarm: --add: 'bob' given more than once: one user, " \
        "one password\n" and out.read_text() == before, proc.stderr


def test_the_controller_without_a_credentials_file_says_how_to_make_one(tmp_path):
    text = (ZDIR / "deploy.json5").read_text().replace('"config/zenoh/credentials.txt"',
                                                     json.dumps(str(tmp_path / "none.txt")))
    (tmp_path / "deploy.json5").write_text(text)
    with pytest.raises(BadInput, match="fishfarm credentials --out"):
        Bus(BusConfig(config=str(tmp_path / "deploy.json5")))


def test_without_access_control_a_user_key_is_a_claim_only():
    """The demo (no ACL): anybody may query .../by/anybody, so the handler is told nobody."""
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    users = []

    async def feed(payload, *, user="unset"):
        users.append(user)
        return {"ok": True}
    try:
        with Bus(BusConfig(listen=[endpoint]), "demo", loop=loop) as bus:
            bus.overrides({"feed": feed})
            assert not bus.identified
            with Bus.client(endpoint, timeout_s=WAIT_S) as tool:
                assert tool.query("override/feed/by/erin", {}) == [{"ok": True}]
                assert tool.query("override/feed", {}) == [{"ok": True}]
    finally:
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
    assert users == [None, None]


def test_an_apply_shaped_entry_gets_the_user_and_old_handlers_do_not():
    """How the integrator wires Overrides.apply(command, payload, *, user=None, origin="zenoh"):
    bus.overrides({name: functools.partial(overrides.apply, name) ...}) — the bus passes user=."""
    got = []

    class Overrides:
        async def apply(self, command, payload, *, user=None, origin="zenoh"):
            got.append((command, payload, user, origin))
            return {"ok": True}

    async def old(payload):
        got.append(("old", payload))
        return {"ok": True}

    async def loose(payload, **kw):
        got.append(("loose", kw))
        return {"ok": True}
    for handler in (functools.partial(Overrides().apply, "feed"), old, loose):
        assert asyncio.run(_with_user(handler)({"tank": "T1"}, user="ana")) == {"ok": True}
    assert got == [("feed", {"tank": "T1"}, "ana", "zenoh"), ("old", {"tank": "T1"}), ("loose", {"user": "ana"})]
