"""The real `fishfarm run` process on the demo farm with `[bus] config` set to deploy.json5 (a free
loopback port, credentials from `fishfarm credentials`): people reach it with `fishfarm status` and
`fishfarm override` as their role allows, a viewer's e-stop latches the real devices, and a second
"controller" logged in with stolen operator credentials can answer nobody's status."""
from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import threading
import time
import tomllib

import pytest
import tomli_w

from controller.bus import Bus
from hil_tests.farm import without_cleaner  # the demo farm's feeder alone
from tests.controller.zenoh_farm import FISHFARM, ROOT, deploy_config, free_port

UP_S = 60.0


@pytest.fixture(scope="module")
def controller(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("deployed")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    zconfig, passwords = deploy_config(tmp, endpoint)
    raw = without_cleaner(tomllib.loads((ROOT / "config" / "farm.toml").read_text()))
    raw["bus"] = {"config": str(zconfig)}
    raw["store"] = {"path": str(tmp / "ledger.db")}
    raw["devices"]["dispenser"]["port"] = 0
    (tmp / "farm.toml").write_text(tomli_w.dumps(raw))
    log_path = tmp / "controller.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "controller.cli", "run", "--config", str(tmp / "farm.toml"),
                                 "--no-console"], cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"}, start_new_session=True)
    try:
        deadline = time.monotonic() + UP_S
        while "controller for site" not in log_path.read_text(errors="replace"):
            assert proc.poll() is None, log_path.read_text(errors="replace")[-3000:]
            assert time.monotonic() < deadline, log_path.read_text(errors="replace")[-3000:]
            time.sleep(0.02)
        yield endpoint, passwords, log_path
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _fishfarm(endpoint, passwords, user, *args):
    return subprocess.run([FISHFARM, *args, "--connect", endpoint, "--user", user, "--password", passwords[user],
                           "--timeout", "5"], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "USER": "tester"})


def test_people_reach_the_deployed_controller_as_their_role_allows(controller):
    endpoint, passwords, log_path = controller
    proc = _fishfarm(endpoint, passwords, "viewer", "status", "--json")
    assert proc.returncode == 0, proc.stderr
    tanks = json.loads(proc.stdout)["tanks"]
    assert tanks
    proc = _fishfarm(endpoint, passwords, "viewer", "override", "reset")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    assert "user 'viewer' may not send this (access control)" in proc.stderr
    proc = _fishfarm(endpoint, passwords, "ana", "override", "ration", "tank=T1", "grams=900")
    assert proc.returncode == 2 and "user 'ana' may not send this (access control)" in proc.stderr   # engineer-only
    # a stolen operator login running a "controller" of its own: its status answers nobody
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    forged = []

    async def forge(payload):
        forged.append(payload)
        return {"site": "demo", "tanks": [], "forged": True}
    try:
        with Bus.client(endpoint, user="operator", password=passwords["operator"], timeout_s=5.0,
                        loop=loop) as impostor:
            impostor.queryable("status", forge)
            with Bus.client(endpoint, user="ana", password=passwords["ana"], timeout_s=5.0) as ana:
                replies = ana.query("status", timeout_s=5.0)
    finally:
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
    assert forged == []
    assert len(replies) == 1 and "forged" not in replies[0] and replies[0]["tanks"]
    # the e-stop, from the least of the roles: the real devices latch
    proc = _fishfarm(endpoint, passwords, "viewer", "override", "estop", "--reason", "test")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == {"ok": True, "confirmed": True}
    # the log and the audit name the login that sent it, the payload's claimed name beside it
    assert "e-stop by viewer" in log_path.read_text(errors="replace")
    rows, deadline = [], time.monotonic() + 10.0
    while not any(r["command"] == "estop" for r in rows):     # written just after the reply
        assert time.monotonic() < deadline, rows
        time.sleep(0.05)
        proc = subprocess.run([FISHFARM, "audit", "--db", str(log_path.parent / "ledger.db"), "--json"],
                              capture_output=True, text=True, timeout=30)
        assert proc.returncode == 0, proc.stderr
        rows = json.loads(proc.stdout)
    (estop,) = [r for r in rows if r["command"] == "estop"]
    assert estop["user"] == "viewer" and estop["ok"], estop
    assert not any(r["command"] == "reset" and r["ok"] for r in rows)      # the viewer's reset never ran
