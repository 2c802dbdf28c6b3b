"""mbpoll reads every address of config/modbus_map.csv from a running controller (`fishfarm run`,
every device simulated) and writes the writable ones; the values agree with `status`."""
import math
import re
import subprocess
import sys
import time
import tomllib

import pytest
import tomli_w

from controller.bus import Bus
from hil_tests.ports import free_port

from .conftest import ROOT, map_rows
from .tooling import mbpoll

TYPE = {"coil": "0", "discrete input": "1", "input register": "3", "holding register": "4"}


def poll(port: int, row: dict, *values) -> tuple[int, str, str]:
    t = TYPE[row["type"]] + {"f32": ":float", "u32": ":int", "i32": ":int"}.get(row["data_type"], "")
    cmd = [mbpoll(), "-m", "tcp", "-a", "1", "-p", str(port), "-0", "-1", "-B", "-o", "5", "-t", t,
           "-r", row["address"], *([] if values else ["-c", "1"]), "127.0.0.1", *[str(v) for v in values]]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
    return r.returncode, r.stdout, r.stderr


def read(port: int, row: dict):
    rc, out, err = poll(port, row)
    assert rc == 0, (row["name"], err)
    m = re.search(rf"^\[{row['address']}\]:\s+(\S+)", out, re.M)     # "65535 (-1)": the first is ours
    assert m, (row["name"], out)
    text = m.group(1)
    if row["data_type"] == "f32":
        return float(text)
    return int(text) & 0xFFFF_FFFF if row["data_type"] == "u32" else int(text)   # mbpoll's :int is signed


@pytest.fixture
def controller(tmp_path):
    raw = tomllib.loads((ROOT / "config" / "farm.toml").read_text())
    zenoh, scada = free_port(), free_port()
    raw["bus"] = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{zenoh}"], "connect": []}
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    raw["scada"].update(port=scada, refresh_s=0.05)
    raw["devices"]["dispenser"]["port"] = 0
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    log = open(tmp_path / "controller.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "controller.cli", "run", "--config", str(tmp_path / "farm.toml"),
                             "--no-console"], cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 60
    while "controller for site" not in (tmp_path / "controller.log").read_text():
        assert proc.poll() is None and time.monotonic() < deadline, (tmp_path / "controller.log").read_text()
        time.sleep(0.05)
    assert f"scada: Modbus TCP on 127.0.0.1:{scada}" in (tmp_path / "controller.log").read_text()
    try:
        yield scada, f"tcp/127.0.0.1:{zenoh}"
    finally:
        proc.terminate()
        assert proc.wait(timeout=30) == 0, (tmp_path / "controller.log").read_text()
        log.close()
        text = (tmp_path / "controller.log").read_text()
        assert "Traceback" not in text and "crashed" not in text, text


def until(check, what: str, wall_s: float = 10.0):
    deadline = time.monotonic() + wall_s
    while not check():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


def test_mbpoll_reads_every_address_and_writes_the_writable(controller):
    port, endpoint = controller
    rows = map_rows()
    by_name = {(r["type"], r["name"]): r for r in rows}
    # the moving cleaner's position is read last, just before the status it is compared with
    moving = [r for r in rows if r["name"] == "cleaner.x_m"]
    values = {(r["type"], r["name"]): read(port, r) for r in rows if r not in moving}
    values |= {(r["type"], r["name"]): read(port, r) for r in moving}
    with Bus.client(endpoint) as bus:
        [status] = bus.query("status")
    assert values[("input register", "tank_count")] == len(status["tanks"]) == 8
    assert values[("input register", "map_version")] == 1 and values[("input register", "word_order")] == 0
    for tank, t in status["tanks"].items():
        assert values[("input register", f"tank.{tank}.stock")] == t["stock"]
        assert values[("input register", f"tank.{tank}.ration_g")] == pytest.approx(t["ration_g"], abs=0.05)
        assert values[("input register", f"tank.{tank}.mean_weight_g")] == pytest.approx(t["mean_weight_g"])
        assert values[("input register", f"tank.{tank}.last_survey_t")] == 0xFFFF_FFFF     # no value: no survey
    cleaner_x = (status.get("cleaner") or {}).get("x_m")        # the demo's pond cleaner, moving meanwhile
    x_m = values[("input register", "cleaner.x_m")]
    assert math.isnan(x_m) if cleaner_x is None else x_m == pytest.approx(cleaner_x, abs=0.5)
    assert values[("input register", "uptime_s")] <= status["uptime_s"] + 1

    # the writable ones: each reaches the controller
    ration = by_name[("holding register", "tank.T3.set_ration_g")]
    rc, _, err = poll(port, ration, 1234.5)
    assert rc == 0, err
    until(lambda: read(port, by_name[("input register", "tank.T3.ration_g")]) == 1234.5, "ration not set")
    with Bus.client(endpoint) as bus:
        assert bus.query("status")[0]["tanks"]["T3"]["ration_g"] == 1234.5
    rc, _, err = poll(port, by_name[("holding register", "tank.T5.feed_now_g")], 20)
    assert rc == 0 or "Slave device or server failure" in err, err      # 04: e.g. a demand already waits
    assert poll(port, by_name[("holding register", "tank.T5.feed_now_g")], 61)[2].strip().endswith(
        "Illegal data value")                                          # more than one portion: 03
    estop = by_name[("coil", "estop")]
    assert poll(port, estop, 1)[0] == 0
    until(lambda: read(port, estop) == 1 and read(port, by_name[("discrete input", "estop_latched")]) == 1,
          "the e-stop coil never read latched")
    assert poll(port, estop, 0)[2].strip().endswith("Illegal data value")   # released only by reset
    assert poll(port, by_name[("coil", "reset")], 1)[0] == 0
    until(lambda: read(port, estop) == 0, "reset did not release the e-stop")
    for r in rows:
        if "W" in r["access"] and r["type"] == "coil" and r["name"] not in ("estop", "reset"):
            rc, _, err = poll(port, r, 1)
            assert rc == 0, (r["name"], err)         # pause, ack_all, an alarm slot's ack
            if r["name"].endswith(".pause"):         # the tank pauses, and resumes on 0
                tank = r["name"].split(".")[1]
                with Bus.client(endpoint) as bus:
                    assert bus.query("status")[0]["tanks"][tank]["paused"] is True, tank
                assert poll(port, r, 0)[0] == 0
                with Bus.client(endpoint) as bus:
                    assert bus.query("status")[0]["tanks"][tank]["paused"] is False, tank
    # and every read-only address refuses a write: 02
    for r in rows[:: max(1, len(rows) // 20)]:
        if "W" not in r["access"] and r["type"] in ("coil", "holding register"):
            assert poll(port, r, 1)[2].strip().endswith("Illegal data address"), r["name"]


def test_generated_writes_never_crash_the_controller(controller):
    """2,000 generated writes (valid and not) on the real controller: it lives, answers status, and a
    valid feed is accepted after. (The guard's exact answers: test_writes.py, 10,000 more.)"""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from .mbap import Mbap, f32_words

    port, endpoint = controller
    client = Mbap(port)
    write = st.tuples(st.sampled_from(["coil", "holding register"]),
                      st.one_of(st.integers(0, 140), st.integers(0, 0xFFFF)),
                      st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=3))

    @settings(max_examples=100, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(st.lists(write, min_size=20, max_size=20))
    def storm(writes):
        for table, address, values in writes:
            values = values[: max(1, min(len(values), 0x10000 - address))]
            got = client.write(table, address, [v & 1 for v in values] if table == "coil" else values)
            assert got is None or got[1] in (2, 3, 4), got

    try:
        assert client.write("coil", 105, [1]) is None      # whatever the storm does, T6 starts it paused
        storm()
        # Undo what the storm may have left in the way of the feed below: the latch, T6 paused
        # (coil 105: a paused tank refuses operator feeds, rightly), T6's ration (set again below).
        assert client.write("coil", 1, [1]) in (None, ("exception", 4))
        assert client.write("coil", 105, [0]) is None
        until(lambda: client.read("coil", 105) == [0], "T6 stayed paused", 30)
        until(lambda: client.read("input register", 10) not in ([7], [2]), "the feeder stayed stopped", 30)
        assert client.write("holding register", 121, f32_words(5000.0, "big"), single=False) is None   # T6
        until(lambda: client.read("input register", 200) == [0], "T6 kept a demand waiting", 30)
        assert client.write("holding register", 120, [20]) is None               # a valid feed, accepted
        with Bus.client(endpoint) as bus:
            [status] = bus.query("status")
        assert status["tanks"]["T6"]["ration_g"] == 5000.0
    finally:
        client.close()
