"""Vision workers over Zenoh (controller/surveys/remote.py, worker.py): the real ``fishfarm worker``
processes on loopback, measuring rendered underwater pairs; results compared with the local
runner's on the same pairs."""
from __future__ import annotations

import json
import logging
import math
import os
import signal
import subprocess
import sys
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest
import zenoh

from controller.cli import main as fishfarm_main
from controller.errors import BadInput
from controller.surveys import wire
from controller.surveys.frames import PairJob, decode_pair
from controller.surveys.remote import PER_WORKER, connect, measure_remote
from controller.surveys.runner import measure_all
from controller.surveys.stop import IN_FLIGHT
from controller.surveys.wiring import workers_or_here
from controller.surveys.worker import node_key
from devices.sim.fish_scene import underwater_rig, underwater_scene
from tests.controller.zenoh_farm import free_port
from vision.survey_types import SurveySetup

FISHFARM = str(Path(sys.executable).with_name("fishfarm"))
WAIT_S = 20.0                    # a worker process's start (imports, connect retry); the VM stalls
SETUP = SurveySetup(up_world=(0.0, 0.0, 1.0))
PAIRS = 6
FRAMES = 12                      # the rendered pairs twice over: more frames than workers x 2 in flight


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """PAIRS rendered underwater pairs on disk, one rig; the local runner's results on FRAMES jobs."""
    folder = tmp_path_factory.mktemp("pairs")
    rig = underwater_rig()
    items = []
    for seed in range(PAIRS):
        sc = underwater_scene(np.random.default_rng(100 + seed), rig=rig)
        paths = (str(folder / f"{seed}_L.png"), str(folder / f"{seed}_R.png"))
        cv2.imwrite(paths[0], sc.left)
        cv2.imwrite(paths[1], sc.right)
        items.append(paths)
    calib = rig.calibration()
    local = list(measure_all(jobs(items), calib, SETUP, workers=1))
    assert sum(len(r.fish) for r in local) >= 5, "the rendered pairs should hold measurable fish"
    return items, calib, local, folder


def jobs(items, n=FRAMES):
    return [PairJob(i, " + ".join(items[i % len(items)]), paths=items[i % len(items)]) for i in range(n)]


def same(results, local) -> None:
    """Frame by frame, fish by fish, bit for bit."""
    assert [r.frame for r in results] == [r.frame for r in local]
    for got, want in zip(results, local, strict=True):
        assert len(got.fish) == len(want.fish), got.frame
        for a, b in zip(got.fish, want.fish, strict=True):
            for name in ("snout_mm", "fork_mm", "snout_px", "fork_px"):
                assert np.array_equal(getattr(a, name), getattr(b, name)), (got.frame, name)
            assert a.score == b.score and a.quality == b.quality


@pytest.fixture
def hub():
    """A session listening on a free loopback port, as ``fishfarm survey --workers`` opens it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session, listening = connect(endpoint)
    assert listening
    site = "t" + uuid.uuid4().hex[:8]
    yield session, endpoint, site
    session.close()


class Workers:
    def __init__(self, tmp_path: Path):
        self.tmp = tmp_path
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, endpoint: str, site: str, worker_id: str, *extra: str, env: dict | None = None):
        log = open(self.tmp / f"{worker_id}.log", "w")  # noqa: SIM115 - the process holds it
        env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[3]), **(env or {})}
        p = subprocess.Popen([FISHFARM, "worker", "--connect", endpoint, "--site", site, "--id", worker_id, *extra],
                             stdout=log, stderr=subprocess.STDOUT, env=env)
        self.procs[worker_id] = p
        return p

    def wait_alive(self, session: zenoh.Session, site: str, *ids: str) -> None:
        deadline = time.monotonic() + WAIT_S
        while True:
            seen = {str(r.ok.key_expr).rsplit("/", 1)[-1]
                    for r in session.liveliness().get(node_key(site, "*"), timeout=2.0) if r.ok is not None}
            if set(ids) <= seen:
                return
            assert time.monotonic() < deadline, f"workers {set(ids) - seen} not up: " + " | ".join(
                (self.tmp / f"{i}.log").read_text()[-300:] for i in ids)

    def stop(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.kill()
            p.wait(timeout=WAIT_S)


@pytest.fixture
def workers(tmp_path):
    w = Workers(tmp_path)
    yield w
    w.stop()


def test_two_workers_measure_exactly_what_the_local_runner_does(rendered, hub, workers):
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    workers.start(endpoint, site, "wa")
    workers.start(endpoint, site, "wb")
    workers.wait_alive(session, site, "wa", "wb")
    results = list(measure_remote(jobs(items), calib, SETUP, session=session, site=site))
    same(results, local)
    assert {r.worker for r in results} == {"wa", "wb"}
    for r in results:
        assert {"decode", "measure", "encode", "transport", "cpu"} <= set(r.timings)


def test_decoded_frames_travel_losslessly(rendered, hub, workers):
    # video jobs carry arrays: they go encoded (BMP), and the worker measures the very same pixels
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    workers.start(endpoint, site, "wv")
    workers.wait_alive(session, site, "wv")
    arrays = [PairJob(i, f"video frame {i}", left=cv2.imread(items[i][0]), right=cv2.imread(items[i][1]))
              for i in range(3)]
    results = list(measure_remote(arrays, calib, SETUP, session=session, site=site))
    same(results, local[:3])
    assert {r.worker for r in results} == {"wv"}


@pytest.mark.parametrize("channels", [1, 3])
def test_a_decoded_frame_goes_as_its_very_pixels_at_the_cost_of_a_copy(channels):
    # grey and colour views, odd sizes, smooth (a compressor would shrink them): what the worker
    # decodes is what the survey held, and the blob is the raw pixels plus a header (no
    # compression to spend the survey's CPU on)
    rng = np.random.default_rng(3)
    shape = (37, 53) if channels == 1 else (37, 53, 3)
    ramp = np.indices(shape).sum(axis=0).astype(np.uint8)
    left, right = ramp, ramp + rng.integers(0, 2, shape, dtype=np.uint8)
    blobs, names = wire.job_blobs(PairJob(0, "video frame 0", left=left, right=right))
    got_left, got_right, _ = decode_pair(blobs, names)
    assert np.array_equal(got_left, left) and np.array_equal(got_right, right)
    assert all(left.size <= len(b) <= left.size + 2048 for b in blobs)


def test_the_survey_stop_keeps_two_pairs_in_flight_per_worker_up(hub, workers):
    # the stop takes frames as fast as the workers up take pairs (2 each), and keeps its own 2
    # when none is up and it measures here
    session, endpoint, site = hub
    measure = workers_or_here(session, site)
    assert measure.in_flight() == IN_FLIGHT == 2
    workers.start(endpoint, site, "wi1")
    workers.start(endpoint, site, "wi2")
    workers.wait_alive(session, site, "wi1", "wi2")
    deadline = time.monotonic() + WAIT_S
    while measure.in_flight() != 4:
        assert time.monotonic() < deadline, measure.in_flight()
        time.sleep(0.05)
    workers.stop()                                # killed: their tokens go with their sessions
    while measure.in_flight() != 2:
        assert time.monotonic() < deadline, measure.in_flight()
        time.sleep(0.05)


def test_a_worker_killed_mid_survey_loses_no_frame_and_repeats_none(rendered, hub, workers, caplog):
    # the victim holds every job it is given (it hangs in them) until it is killed: each of those
    # frames can only come back by being re-run elsewhere
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    measure = "tests.controller.surveys.standin:measure_or_hang"
    victim = workers.start(endpoint, site, "victim", "--measure", measure, env={"FISHFARM_TEST_HANG": "1"})
    workers.start(endpoint, site, "steady", "--measure", measure)
    workers.wait_alive(session, site, "victim", "steady")
    results = []
    with caplog.at_level("WARNING", logger="fishfarm.survey"):
        for r in measure_remote(jobs(items), calib, SETUP, session=session, site=site, measure=measure):
            if not results:
                victim.send_signal(signal.SIGKILL)
            results.append(r)
    same(results, local)
    assert {r.worker for r in results} == {"steady"}
    assert any("vision worker victim" in m for m in caplog.messages), caplog.messages
    assert victim.wait(timeout=WAIT_S) == -signal.SIGKILL


def test_with_no_worker_up_the_survey_is_measured_here(rendered, hub):
    items, calib, local, _ = rendered
    session, _, site = hub
    results = list(measure_remote(jobs(items, 4), calib, SETUP, session=session, site=site, discover_s=0.2,
                                  local_workers=1))
    same(results, local[:4])
    assert {r.worker for r in results} == {None}


def _fake_worker(session: zenoh.Session, site: str, answer, name: str = "liar"):
    """An in-process 'worker' answering every job with ``answer(header)`` (bytes) or never (None)."""
    held = []

    def on_query(query):
        header, _ = wire.decode_job(bytes(query.payload.to_bytes()))
        data = answer(header)
        if data is None:
            held.append(query)               # never answered: the survey's timeout must act
            return
        query.reply(query.key_expr, data)
        query.drop()
    key = node_key(site, name)
    entities = [session.declare_queryable(f"{key}/pair", on_query), session.liveliness().declare_token(key)]
    return entities, held


GARBAGE = {
    "not json": lambda h: b"\x00\xff not json",
    "no ok": lambda h: b'{"fish": []}',
    "another job": lambda h: json.dumps({"ok": True, "job": "someone-else", "fish": []}).encode(),
    "bad fish": lambda h: json.dumps({"ok": True, "job": h["job"], "fish": [{"snout_mm": [1, 2]}]}).encode(),
    "fish not objects": lambda h: json.dumps({"ok": True, "job": h["job"], "fish": [3]}).encode(),
    "refusal": lambda h: json.dumps({"ok": False, "job": h["job"], "kind": "internal", "error": "boom"}).encode(),
    # well formed, not a fish of the species (SETUP's plausible fork lengths): a rogue reply of 100 m
    # fish once set a ration of 4.6e14 g
    "a fish 100 m long": lambda h: _one_fish(h, [0.0, 0.0, 1000.0], [1e5, 0.0, 1000.0]),
    "a fish at the bound and one beyond": lambda h: _one_fish(
        h, [0.0, 0.0, 1000.0], [10 * SETUP.geometry.max_length_cm, 0.0, 1000.0], beyond=True),
    "a fish 1 mm long": lambda h: _one_fish(h, [0.0, 0.0, 1000.0], [1.0, 0.0, 1000.0]),
    "a fish at no place": lambda h: _one_fish(h, [0.0, 0.0, 1000.0], [float("nan"), 0.0, 1000.0]),
    "silent": lambda h: None,
}


def _one_fish(h, snout, fork, beyond=False) -> bytes:
    fish = [{"snout_mm": snout, "fork_mm": fork, "snout_px": [[1, 2], [3, 4]], "fork_px": [[5, 6], [7, 8]],
             "score": 0.9}]
    if beyond:            # the bound itself is a fish; the first past it is not
        fish.append({**fish[0], "fork_mm": [fork[0] * (1 + 1e-3), *fork[1:]]})
    return json.dumps({"ok": True, "job": h["job"], "fish": fish}).encode()


@pytest.mark.parametrize("kind", list(GARBAGE))
def test_a_worker_answering_garbage_is_dropped_and_its_jobs_run_elsewhere(rendered, hub, kind):
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    liar = zenoh.open(wire_client(endpoint))
    try:
        entities, held = _fake_worker(liar, site, GARBAGE[kind])
        results = list(measure_remote(jobs(items, 3), calib, SETUP, session=session, site=site,
                                      timeout_s=1.0, local_workers=1, discover_s=WAIT_S))
        same(results, local[:3])
        assert {r.worker for r in results} == {None}        # the only worker was the liar: all here
        assert (len(held) >= 1) == (kind == "silent")
        for q in held:
            q.drop()
        for e in entities:
            e.undeclare()
    finally:
        liar.close()


def wire_client(endpoint: str):
    from controller.zenoh_config import client_config
    return client_config(endpoint)


def _ask(session, site, worker_id, payload: bytes) -> dict:
    replies = list(session.get(f"{node_key(site, worker_id)}/pair", payload=payload, timeout=WAIT_S))
    assert len(replies) == 1 and replies[0].ok is not None
    return json.loads(replies[0].ok.payload.to_bytes())


def test_a_worker_refuses_unknown_calibrations_and_non_jobs_and_serves_on(rendered, hub, workers):
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    workers.start(endpoint, site, "wq")
    workers.wait_alive(session, site, "wq")
    blobs, names = wire.job_blobs(jobs(items, 1)[0])
    header = {"job": "j1", "frame": 0, "where": "x", "names": list(names), "setup": wire.setup_to_json(SETUP),
              "measure": "vision.survey:measure_pair", "calib": wire.content_hash(b"nobody has this")}
    reply = _ask(session, site, "wq", wire.encode_job(header, blobs))
    assert reply["ok"] is False and reply["kind"] == "calibration" and "unknown" in reply["error"]
    assert reply["job"] == "j1"
    reply = _ask(session, site, "wq", b"FFJ1\xff\xff\xff\xffgarbage")
    assert reply["ok"] is False and reply["kind"] == "refused" and "not a job" in reply["error"]
    nested = b'{"a":' * 100_000                       # a header nested past the parser's stack
    reply = _ask(session, site, "wq", b"FFJ1" + len(nested).to_bytes(4, "big") + nested)
    assert reply["ok"] is False and reply["kind"] == "refused" and "nested deeper" in reply["error"]
    reply = _ask(session, site, "wq", wire.encode_job({**header, "measure": "os:system"}, blobs))
    assert reply["ok"] is False and reply["kind"] == "refused" and "measures with" in reply["error"]
    # a calibration served under a hash its content does not have is not taken
    forged = session.declare_queryable(f"farm/{site}/worker/calib/{'0' * 64}",
                                       lambda q: (q.reply(q.key_expr, wire.calibration_bytes(calib)), q.drop()))
    reply = _ask(session, site, "wq", wire.encode_job({**header, "calib": "0" * 64}, blobs))
    forged.undeclare()
    assert reply["ok"] is False and reply["kind"] == "calibration"
    results = list(measure_remote(jobs(items, 2), calib, SETUP, session=session, site=site))
    same(results, local[:2])
    assert {r.worker for r in results} == {"wq"}


def test_a_pair_at_fault_stops_the_survey_as_it_would_locally(rendered, hub, workers, tmp_path):
    items, calib, _, _ = rendered
    session, endpoint, site = hub
    workers.start(endpoint, site, "wf")
    workers.wait_alive(session, site, "wf")
    bad = tmp_path / "bad_R.png"
    bad.write_text("not a picture")
    broken = [PairJob(0, "p", paths=(items[0][0], str(bad)))]
    with pytest.raises(BadInput) as local_error:
        list(measure_all(broken, calib, SETUP, workers=1))
    with pytest.raises(BadInput) as remote_error:
        list(measure_remote(broken, calib, SETUP, session=session, site=site))
    assert str(remote_error.value) == str(local_error.value)
    assert str(bad) in str(remote_error.value)


def test_survey_command_with_workers_writes_the_local_survey(rendered, workers, tmp_path):
    # the survey listens at the endpoint itself; the worker, started first, joins it on retry
    _, calib, _, folder = rendered
    calib_path = tmp_path / "calib.json"
    calib_path.write_text(json.dumps(calib.to_json()))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    workers.start(endpoint, "demo", "wc")
    deadline = time.monotonic() + WAIT_S
    while "retrying" not in (tmp_path / "wc.log").read_text():    # up, and knocking every second
        assert time.monotonic() < deadline, (tmp_path / "wc.log").read_text()
        time.sleep(0.05)
    args = ["survey", "--calib", str(calib_path), "--species", "sparus_aurata", "--setup", "underwater",
            "--dir", str(folder), "--up", "0,0,1"]
    assert fishfarm_main([*args, "--json", str(tmp_path / "local.json"), "--workers", "1"]) == 0
    assert fishfarm_main([*args, "--json", str(tmp_path / "remote.json"), "--workers", endpoint]) == 0
    here, there = (json.loads((tmp_path / f).read_text()) for f in ("local.json", "remote.json"))
    assert there["fish"] == here["fish"] and there["count"] == here["count"] and there["frames"] == PAIRS
    assert "transport" in there["stage_ms"] and "transport" not in here["stage_ms"]


@pytest.mark.parametrize("value", ["many", "tcp/127.0.0.1:99999"])
def test_survey_command_refuses_a_bad_workers_value(capsys, rendered, tmp_path, value):
    """A port out of range was blamed on --connect, an option the survey has not (outside tester)."""
    from controller.cli.calib_io import save_calibration
    items, calib = rendered[0], rendered[1]
    save_calibration(calib, str(tmp_path / "c.json"))
    args = ["survey", "--calib", str(tmp_path / "c.json"), "--species", "sparus_aurata", "--setup",
            "underwater", "--pair", *items[0], "--json", str(tmp_path / "o.json"), "--workers", value]
    assert fishfarm_main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--workers" in err[0] and value in err[0] and "--connect" not in err[0], err


def test_worker_command_refuses_bad_options(capsys):
    assert fishfarm_main(["worker", "--cpu", "9999"]) == 2
    assert fishfarm_main(["worker", "--site", "a/b"]) == 2
    for seconds in ("nan", "inf", "-1"):                # (nan would serve for ever, inf overflow the timer)
        assert fishfarm_main(["worker", "--duration", seconds]) == 2
    ids = ("a/b*", "x?y", "**", "", "w" * 65)             # cleaned silently before: two could come out one
    for worker_id in ids:
        assert fishfarm_main(["worker", "--id", worker_id]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 5 + len(ids) and "--cpu" in err[0] and "--site" in err[1]
    assert all("--duration" in line and s in line for line, s in zip(err[2:5], ("nan", "inf", "-1"), strict=True))
    assert all("--id" in line and repr(i) in line for line, i in zip(err[5:], ids, strict=True))


def test_a_login_given_by_half_is_refused_naming_the_missing_option(capsys):
    # --user alone logged in with an empty password, was refused, and the worker retried for ever
    assert fishfarm_main(["worker", "--user", "worker", "--connect", "tcp/127.0.0.1:9"]) == 2
    assert fishfarm_main(["worker", "--password", "pw", "--connect", "tcp/127.0.0.1:9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2, err
    assert "--password" in err[0] and "--user was given" in err[0], err
    assert "--user" in err[1] and "--password was given" in err[1], err


def test_a_second_worker_under_a_taken_name_is_refused_and_a_restarted_one_is_not(hub, workers):
    # two workers of one --id both answered every job (each measured twice, 3x slower)
    session, endpoint, site = hub
    first = workers.start(endpoint, site, "dup")
    workers.wait_alive(session, site, "dup")
    workers.procs["dup-2"] = second = subprocess.Popen(
        [FISHFARM, "worker", "--connect", endpoint, "--site", site, "--id", "dup"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[3])})
    _, err = second.communicate(timeout=WAIT_S + 10)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert second.returncode == 2 and "--id" in lines[-1] and "'dup'" in lines[-1], err
    assert first.poll() is None                      # the one serving is left alone
    first.kill()                                     # a service restarted after a crash: same name
    first.wait(timeout=WAIT_S)
    workers.start(endpoint, site, "dup")
    workers.wait_alive(session, site, "dup")
    assert workers.procs["dup"].poll() is None


def test_the_controller_measures_through_its_own_bus_session(rendered, workers):
    # the scheduled surveys run in the controller: its Bus (peer, listening) is the workers' hub
    from controller.bus import Bus
    from controller.config import BusConfig
    items, calib, local, _ = rendered
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = Bus(BusConfig(mode="peer", listen=[endpoint], connect=[]), site="farmx")
    try:
        workers.start(endpoint, "farmx", "wctl")
        workers.wait_alive(bus.session, "farmx", "wctl")
        results = list(measure_remote(jobs(items, 2), calib, SETUP, session=bus.session, site=bus.site))
    finally:
        bus.close()
    same(results, local[:2])
    assert {r.worker for r in results} == {"wctl"}


def test_worker_command_reads_its_config_or_says_what_is_wrong(tmp_path, capsys):
    assert fishfarm_main(["worker", "--config", str(tmp_path / "none.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.toml" in err[0]


def test_a_late_answer_from_a_worker_given_up_on_is_not_counted_twice(rendered, hub):
    # the worker's token goes while it holds two jobs (re-run here at once); its right answers
    # come afterwards, or before, whichever: each frame is in the results once
    import threading
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    late = zenoh.open(wire_client(endpoint))
    key = node_key(site, "late")
    token = late.liveliness().declare_token(key)
    gone = threading.Event()
    threads = []

    def answer_later(query):
        header, _ = wire.decode_job(bytes(query.payload.to_bytes()))
        if not gone.is_set():
            gone.set()
            token.undeclare()
        gone.wait()
        time.sleep(0.3)          # only orders the two answers one way more often; both ways pass
        fish = [wire.fish_to_json(f) for f in local[header["frame"]].fish]
        query.reply(query.key_expr, wire.encode_reply({"ok": True, "job": header["job"], "frame": header["frame"],
                                                       "fish": fish, "timings": {}}))
        query.drop()

    def on_query(query):
        t = threading.Thread(target=answer_later, args=(query,))
        threads.append(t)
        t.start()
    queryable = late.declare_queryable(f"{key}/pair", on_query)
    try:
        results = list(measure_remote(jobs(items, 4), calib, SETUP, session=session, site=site, local_workers=1,
                                      discover_s=WAIT_S))
        for t in threads:
            t.join(WAIT_S)
    finally:
        queryable.undeclare()
        late.close()
    same(results, local[:4])
    assert gone.is_set() and len(threads) >= 1


def heard(measure, workers: int) -> None:
    """Wait until the survey stop's measure has heard ``workers`` workers' tokens."""
    deadline = time.monotonic() + WAIT_S
    while measure.in_flight() != workers * PER_WORKER:
        assert time.monotonic() < deadline, measure.in_flight()
        time.sleep(0.01)


def honest_reply(local, header) -> bytes:
    """A worker's reply with the fish the local runner measured in that frame."""
    fish = [wire.fish_to_json(f) for f in local[header["frame"]].fish]
    return wire.encode_reply({"ok": True, "job": header["job"], "frame": header["frame"], "fish": fish, "timings": {}})


def test_pairs_sent_one_call_each_as_the_survey_stop_does_are_shared_by_the_workers(rendered, hub):
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    served: dict[str, list[int]] = {"w1": [], "w2": []}

    def honest(name):
        def answer(header):
            served[name].append(header["frame"])
            return honest_reply(local, header)
        return answer
    peer = zenoh.open(wire_client(endpoint))
    measure = workers_or_here(session, site, discover_s=WAIT_S)        # the survey stop's own
    try:
        entities = [e for name in served for e in _fake_worker(peer, site, honest(name), name)[0]]
        heard(measure, 2)
        for frame in range(8):
            [result] = measure(jobs(items, 8)[frame:frame + 1], calib, SETUP)
            same([result], local[frame:frame + 1])
        for e in entities:
            e.undeclare()
    finally:
        measure.tokens.undeclare()
        peer.close()
    assert sorted(served["w1"] + served["w2"]) == list(range(8))          # each pair measured once
    assert served["w1"] and served["w2"] and abs(len(served["w1"]) - len(served["w2"])) <= 1, served


def test_a_worker_dropped_by_one_pair_is_not_asked_again_by_the_next_pairs(rendered, hub, caplog):
    """The survey stop asks once a pair: a worker that refused (or hung) is benched for the
    pairs after it, said once, and used again at once when its token comes again (restarted)."""
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    asked: dict[str, list[int]] = {"liar": [], "honest": []}

    def answer_as(name):
        def answer(header):
            asked[name].append(header["frame"])
            if name == "liar":
                return json.dumps({"ok": False, "job": header["job"], "kind": "internal", "error": "boom"}).encode()
            return honest_reply(local, header)
        return answer
    peer = zenoh.open(wire_client(endpoint))
    measure = workers_or_here(session, site, discover_s=WAIT_S)
    caplog.set_level(logging.WARNING, logger="fishfarm.survey")
    try:
        liar, _ = _fake_worker(peer, site, answer_as("liar"), "liar")
        honest, _ = _fake_worker(peer, site, answer_as("honest"), "honest")
        heard(measure, 2)
        for frame in range(6):
            [result] = measure(jobs(items, 6)[frame:frame + 1], calib, SETUP)
            same([result], local[frame:frame + 1])
        assert len(asked["liar"]) == 1, asked                              # once, then benched
        assert sorted(asked["honest"]) == list(range(6))
        said = [r for r in caplog.records if "vision worker liar" in r.getMessage()]
        assert len(said) == 1, [r.getMessage() for r in said]
        # restarted: its token goes and comes again, and it is asked again
        for e in liar:
            e.undeclare()
        liar, _ = _fake_worker(peer, site, answer_as("liar"), "liar")
        deadline = time.monotonic() + WAIT_S
        while len(asked["liar"]) < 2:
            assert time.monotonic() < deadline, asked
            [result] = measure(jobs(items, 6)[:1], calib, SETUP)
            same([result], local[:1])
        for e in liar + honest:
            e.undeclare()
    finally:
        measure.tokens.undeclare()
        peer.close()


def test_measuring_here_for_want_of_workers_is_said_once_for_a_visit_s_pairs(rendered, hub, caplog, monkeypatch):
    """The survey stop dispatches each pair on its own: with its only worker benched, every pair of
    a visit said 'no usable vision worker left' (3-4 lines in half a second, an outside tester)."""
    from controller.surveys import remote
    monkeypatch.setattr(remote, "_said_here", [-math.inf], raising=False)
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    peer = zenoh.open(wire_client(endpoint))
    measure = workers_or_here(session, site, discover_s=1.0)     # (each pair waits this for a usable one)
    caplog.set_level(logging.WARNING, logger="fishfarm.survey")
    try:
        liar, _ = _fake_worker(peer, site, GARBAGE["refusal"], "liar")
        heard(measure, 1)
        # the stop keeps pairs in flight at once: each its own dispatch, each finding the worker gone
        with ThreadPoolExecutor(3) as pool:
            results = list(pool.map(lambda f: next(iter(measure(jobs(items, 3)[f:f + 1], calib, SETUP))), range(3)))
        same(results, local[:3])
        said = [r for r in caplog.records if "measuring the rest here" in r.getMessage()]
        assert len(said) == 1, [r.getMessage() for r in said]
        for e in liar:
            e.undeclare()
    finally:
        peer.close()


def test_a_worker_restarted_under_its_name_mid_survey_is_used_at_once(rendered, hub, caplog):
    """One survey, one dispatch: a worker that failed a job was benched by its name for 120 s, so
    the same --id restarted (a service's usual setup) was never asked again and the survey measured
    the rest in its own process (an outside tester). Its new token puts it back at once."""
    items, calib, local, _ = rendered
    session, endpoint, site = hub
    asked: list[int] = []
    state = {"broken": True}

    def answer(header):
        asked.append(header["frame"])
        if state["broken"]:
            return json.dumps({"ok": False, "job": header["job"], "kind": "internal", "error": "boom"}).encode()
        return honest_reply(local, header)
    peer = zenoh.open(wire_client(endpoint))
    measure = workers_or_here(session, site, discover_s=WAIT_S)
    caplog.set_level(logging.WARNING, logger="fishfarm.survey")
    worker = {}
    worker["w"], _ = _fake_worker(peer, site, answer, "w")
    try:
        heard(measure, 1)

        def restarting_jobs():
            for k, job in enumerate(jobs(items, 8)):
                if k == 3:                             # the broken one gone, the same name back
                    for e in worker["w"]:
                        e.undeclare()
                    state["broken"] = False
                    worker["w"], _ = _fake_worker(peer, site, answer, "w")
                    time.sleep(0.2)
                yield job
        results = list(measure(restarting_jobs(), calib, SETUP))
        same(results, local[:8])
        assert not state["broken"] and len([f for f in asked if f >= 3]) >= 3, asked     # the new one measured
    finally:
        for e in worker["w"]:
            e.undeclare()
        measure.tokens.undeclare()
        peer.close()
