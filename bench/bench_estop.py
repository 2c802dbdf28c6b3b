"""E-stop latency under load, on the real processes (simulator + controller over Zenoh, Modbus TCP
and slcan on a pty).

The controller runs 100 tanks (farm clock ``BENCH_ESTOP_SPEED`` x the wall, so the robot is busy
travelling, dispensing and refilling); meanwhile a client floods ``status`` queries and a Zenoh
subscriber on ``farm/**`` stalls (its callback blocks for good); each in a process of its own. The
bench sends ``BENCH_ESTOP_N`` e-stops (payloads cycling through empty, JSON, 1,000-level nested
JSON and bytes that are not JSON), each followed by a reset once the robot is stopped, and
measures, for each:

- ``dispenser``: the simulated PLC's latch instant (its own wall clock, truth log ``estop``) minus
  the instant the query was sent: the auger is off and the gate closed from then on;
- ``drive``: the same at the simulated motor controller: braking starts (the carriage then rolls
  v²/2a, a property of the drive, not of the controller);
- ``stopped``: the later of the two — "auger and drive stopped" — goal p99 <= 10 ms;
- ``reply``: when the reply to the query arrived (the controller replies once both confirmed).

Run: ``.venv/bin/python bench/bench_estop.py``; prints one JSON object.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from controller.bus import Bus  # noqa: E402
from hil_tests.farm import HilFarm  # noqa: E402

N = int(os.environ.get("BENCH_ESTOP_N", "120"))
SPEED = float(os.environ.get("BENCH_ESTOP_SPEED", "5"))
TANKS = 100
GOAL_MS = 10.0
PAYLOADS = [b"", b'{"operator":"bench","reason":"latency"}', b"[" * 1000 + b"]" * 1000,
            b'{"a":' * 1000 + b"1" + b"}" * 1000, bytes(range(256))]

STALLER = """
import sys, time, zenoh
conf = zenoh.Config()
for key, value in (("mode", '"client"'), ("connect/endpoints", '["%s"]'), ("listen/endpoints", "[]"),
                   ("scouting/multicast/enabled", "false"), ("scouting/gossip/enabled", "false")):
    conf.insert_json5(key, value)
session = zenoh.open(conf)
sub = session.declare_subscriber("farm/**", lambda sample: time.sleep(3600))   # stalls for good
print("stalling", flush=True)
time.sleep(float(sys.argv[1]))
"""


def pct(values, q):
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))] if values else None


def figures(ms: list[float]) -> dict:
    return {"p50_ms": round(pct(ms, 0.5), 2), "p99_ms": round(pct(ms, 0.99), 2), "max_ms": round(max(ms), 2)}


class Truth:
    """Follows the simulator's truth log as it grows."""

    def __init__(self, path: Path):
        self.path, self.offset, self.estops = path, 0, []

    def poll(self) -> None:
        with open(self.path, encoding="utf-8") as fh:
            fh.seek(self.offset)
            while (line := fh.readline()).endswith("\n"):
                self.offset = fh.tell()
                record = json.loads(line)
                if record["kind"] == "estop":
                    self.estops.append(record)

    def first_after(self, device: str, t0: float, wait_s: float = 2.0) -> float | None:
        deadline = time.time() + wait_s
        while True:
            self.poll()
            hits = [r["wall"] for r in self.estops if r["device"] == device and r["wall"] >= t0 - 1e-3]
            if hits or time.time() > deadline:
                return min(hits) if hits else None
            time.sleep(0.005)


FLOODER = """
import sys, time
sys.path.insert(0, %r)
from controller.bus import Bus
count, until = 0, time.monotonic() + float(sys.argv[1])
with Bus.client(%r, site=%r, timeout_s=5.0) as bus:
    print("flooding", flush=True)
    while time.monotonic() < until and not sys.stdin.closed:
        bus.query("status", timeout_s=2.0)
        count += 1
        if count %% 100 == 0:
            print(count, flush=True)
"""


def feeder_state(bus: Bus) -> str | None:
    replies = bus.query("status", timeout_s=2.0)
    return replies[0].get("feeder", {}).get("state") if replies else None


def main() -> dict:
    tanks = [{"id": f"T{i}", "stock": 4000, "mean_weight_g": 40.0, "position_m": 2.0 + 0.8 * i,
              "sensors": [f"T{i}-a", f"T{i}-b"]} for i in range(1, TANKS + 1)]
    # hungry fish that ask hard and soon: the robot always has a tank to travel to and feed
    fish = {"ration_pct_day": 20.0, "hunger_threshold_g": 10.0, "initial_hunger": 2.0, "rate_hz": [1.0, 2.0],
            "duration_s": [600.0, 600.0], "rest_s": 0.0}
    overrides = {"tanks": tanks, "feeding": {"portion_g": 20.0},
                 "sim": {"rail": {"rail_length_m": 2.0 + 0.8 * TANKS + 5.0}, "fish": fish}}
    farm = HilFarm(Path(tempfile.mkdtemp(prefix="bench-estop-")), speed=SPEED, overrides=overrides)
    stop = threading.Event()
    counts = [0]
    staller = flooder = None
    stopped, disp, drive, reply, states, unconfirmed, missing = [], [], [], [], {}, 0, 0
    try:
        farm.start_sim()
        farm.start_controller()
        farm.wait_controller_up()
        endpoint, site = f"tcp/127.0.0.1:{farm.zenoh_port}", farm.config.get("site", "demo")
        staller = subprocess.Popen([sys.executable, "-c", STALLER % endpoint, "3600"], stdout=subprocess.PIPE,
                                   text=True)
        assert staller.stdout.readline().strip() == "stalling"
        # the flood comes from a process of its own, so it never competes with the e-stop's sender
        flooder = subprocess.Popen([sys.executable, "-c", FLOODER % (str(ROOT), endpoint, site), "3600"],
                                   stdout=subprocess.PIPE, text=True)
        assert flooder.stdout.readline().strip() == "flooding"
        threading.Thread(target=lambda: [counts.__setitem__(0, int(n)) for n in flooder.stdout],
                         daemon=True).start()
        truth = Truth(farm.truth_path)
        with Bus.client(endpoint, site=site, timeout_s=5.0) as bus:
            time.sleep(3.0)                                   # the robot gets going
            for i in range(N):
                state = feeder_state(bus)
                states[state] = states.get(state, 0) + 1
                t0 = time.time()
                answers = list(bus.session.get(bus.key("override/estop"), payload=PAYLOADS[i % len(PAYLOADS)],
                                               timeout=5.0))
                t_reply = time.time()
                ok = [json.loads(a.ok.payload.to_bytes()) for a in answers if a.ok is not None]
                if not ok or not ok[0].get("confirmed"):
                    unconfirmed += 1
                d, r = truth.first_after("dispenser", t0), truth.first_after("rail", t0)
                if d is None or r is None:
                    missing += 1
                else:
                    disp.append(1000 * (d - t0))
                    drive.append(1000 * (r - t0))
                    stopped.append(1000 * (max(d, r) - t0))
                reply.append(1000 * (t_reply - t0))
                time.sleep(0.2)
                bus.query("override/reset", {"operator": "bench", "reason": "next e-stop"}, timeout_s=5.0)
                deadline = time.time() + 20.0
                while feeder_state(bus) in ("estop", "homing") and time.time() < deadline:
                    time.sleep(0.05)
                time.sleep(0.3 + 0.5 * (i % 3))               # let it get moving again
        farm.check_alive()
    finally:
        stop.set()
        if flooder is not None:
            flooder.kill()
            flooder.wait()
        if staller is not None:
            staller.kill()
            staller.wait()
        farm.stop()
    if not stopped:
        return {"samples": 0, "goal_met": False, "error": "no e-stop reached both devices"}
    return {"tanks": TANKS, "speed": SPEED, "samples": len(stopped), "missing": missing,
            "unconfirmed_replies": unconfirmed, "robot_states_at_estop": states,
            "stopped": figures(stopped), "dispenser": figures(disp), "drive": figures(drive),
            "reply": figures(reply), "status_queries_flooded": counts[0],
            "goal_p99_ms": GOAL_MS, "goal_met": pct(stopped, 0.99) <= GOAL_MS and missing == 0}


if __name__ == "__main__":
    from bench import no_arguments

    no_arguments(__doc__)
    print(json.dumps(main(), indent=2))
