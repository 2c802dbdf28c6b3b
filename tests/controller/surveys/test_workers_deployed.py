"""Vision workers and history on a deployed farm (config/zenoh/deploy.json5: authentication, default
deny): the controller is the router, `fishfarm worker --user worker` serves it, an engineer's
`fishfarm survey --workers ENDPOINT --user ...` borrows the same workers, people of every role read
the history; nobody else serves jobs and the worker login reaches nothing else."""
from __future__ import annotations

import json

import pytest
import zenoh

from controller.cli import main as fishfarm_main
from controller.surveys.remote import measure_remote
from controller.surveys.worker import calib_key, node_key
from controller.zenoh_config import client_config
from tests.controller.surveys.test_remote import PAIRS, SETUP, jobs, rendered, same, workers  # noqa: F401
from tests.controller.zenoh_farm import WAIT_S, start_farm


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    farm, stop = start_farm(tmp_path_factory.mktemp("deployed"))
    asked = []

    async def history(payload, *, key, params):
        asked.append((key, params))
        return {"ok": True, "columns": ["time"], "rows": [], "key": key}
    farm.bus.queryable("history/*/*", history, lenient=True, selector=True)
    farm.asked = asked
    yield farm
    stop()


def session(farm, user: str) -> zenoh.Session:
    return zenoh.open(client_config(farm.endpoint, user, farm.passwords[user], timeout_s=WAIT_S))


def answers(s: zenoh.Session, key: str, payload: bytes | None = None) -> list:
    return [r.ok.payload.to_bytes() if r.ok is not None else r.err.payload.to_bytes()
            for r in s.get(key, payload=payload, timeout=2.0)]


def login(farm, user: str) -> list[str]:
    return ["--user", user, "--password", farm.passwords[user]]


def test_a_logged_in_worker_serves_the_deployed_controller(rendered, farm, workers):  # noqa: F811
    items, calib, local, _ = rendered
    workers.start(farm.endpoint, "demo", "wdep", *login(farm, "worker"))
    workers.wait_alive(farm.bus.session, "demo", "wdep")
    results = list(measure_remote(jobs(items, 2), calib, SETUP, session=farm.bus.session, site="demo"))
    same(results, local[:2])
    assert {r.worker for r in results} == {"wdep"}     # it fetched the calibration, measured, replied


def test_an_engineer_surveys_through_the_router_with_the_farms_workers(rendered, farm, workers, tmp_path):  # noqa: F811
    _, calib, _, folder = rendered
    calib_path = tmp_path / "calib.json"
    calib_path.write_text(json.dumps(calib.to_json()))
    workers.start(farm.endpoint, "demo", "weng", *login(farm, "worker"))
    workers.wait_alive(farm.bus.session, "demo", "weng")
    args = ["survey", "--calib", str(calib_path), "--species", "sparus_aurata", "--setup", "underwater",
            "--dir", str(folder), "--up", "0,0,1"]
    assert fishfarm_main([*args, "--json", str(tmp_path / "local.json"), "--workers", "1"]) == 0
    assert fishfarm_main([*args, "--json", str(tmp_path / "remote.json"), "--workers", farm.endpoint,
                          *login(farm, "engineer")]) == 0
    here, there = (json.loads((tmp_path / f).read_text()) for f in ("local.json", "remote.json"))
    assert there["fish"] == here["fish"] and there["frames"] == PAIRS
    assert "transport" in there["stage_ms"]            # measured by the worker, not here


def test_a_survey_login_that_fails_says_so_in_one_line(rendered, farm, tmp_path, capsys):  # noqa: F811
    _, calib, _, folder = rendered
    (tmp_path / "c.json").write_text(json.dumps(calib.to_json()))
    args = ["survey", "--calib", str(tmp_path / "c.json"), "--species", "sparus_aurata", "--setup", "underwater",
            "--dir", str(folder), "--json", str(tmp_path / "o.json")]
    assert fishfarm_main([*args, "--workers", farm.endpoint, "--user", "engineer", "--password", "wrong"]) == 2
    assert fishfarm_main([*args, "--workers", "2", "--user", "engineer"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "--workers" in err[0] and "engineer" in err[0] and "--user" in err[1]


@pytest.mark.parametrize("stolen", ["viewer", "operator", "engineer"])
def test_no_other_login_can_pose_as_a_worker(farm, stolen):
    """A client with a person's login declares a worker's queryable and token: the controller
    neither sees the token nor reaches the queryable, so no frame of a survey goes to it."""
    forged = []
    with session(farm, stolen) as impostor:
        fake_id = f"fake-{stolen}"
        q = impostor.declare_queryable(f"{node_key('demo', fake_id)}/pair",
                                       lambda query: (forged.append(1), query.reply(query.key_expr, b"garbage")))
        token = impostor.liveliness().declare_token(node_key("demo", fake_id))
        # a round trip on the impostor's link, behind its declarations: the router has had them
        assert answers(impostor, "farm/demo/status")
        seen = {str(r.ok.key_expr) for r in farm.bus.session.liveliness().get(node_key("demo", "*"), timeout=2.0)
                if r.ok is not None}
        assert node_key("demo", fake_id) not in seen
        assert answers(farm.bus.session, f"{node_key('demo', fake_id)}/pair", b"job") == []
        token.undeclare()
        q.undeclare()
    assert forged == []


def test_the_worker_login_reaches_nothing_but_its_jobs_and_the_estop(farm):
    """(E-stop is open to every authenticated login: a vision worker's machine too.)"""
    heard = []
    farm.bus.session.declare_queryable(calib_key("demo", "abc"), lambda q: q.reply(q.key_expr, b"calibration"))
    with session(farm, "worker") as w:
        w.declare_subscriber("farm/**", lambda s: heard.append(str(s.key_expr)))
        assert answers(w, "farm/demo/status") == []
        assert answers(w, "farm/demo/override/reset", b"{}") == []
        assert answers(w, "farm/demo/override/estop", b"{}") != []
        assert answers(w, "farm/demo/history/surveys/T1") == []
        w.put("farm/demo/alarm/feeder", b'{"forged": true}')
        # what it may do, a round trip behind the rest on its link
        assert answers(w, calib_key("demo", "abc")) == [b"calibration"]
        farm.drain()
        farm.bus.publish("feeder/state", {"state": "idle"}, reliable=True)
        assert answers(w, calib_key("demo", "abc")) == [b"calibration"]
    assert "farm/demo/feeder/state" not in heard       # (its own put it hears in its own session)
    assert all(payload.get("forged") is None for _, payload in list(farm.heard.queue))


@pytest.mark.parametrize("user", ["viewer", "operator", "engineer"])
def test_every_role_reads_the_history(farm, user):
    farm.asked.clear()
    with session(farm, user) as s:
        got = answers(s, "farm/demo/history/fish/T3?since=7d")
    assert [json.loads(g) for g in got] == [{"ok": True, "columns": ["time"], "rows": [],
                                            "key": "history/fish/T3"}]
    assert farm.asked == [("history/fish/T3", {"since": "7d"})]
