"""SCADA under load, on the real processes (simulator + controller, Modbus TCP, Zenoh, slcan on a pty).

The controller runs 100 tanks (farm clock ``BENCH_SCADA_SPEED`` x the wall: the robot travels,
dispenses and refills), and 4 SCADA connections, each a process of its own speaking raw Modbus TCP,
poll tank blocks (input registers, 20 words a read) as fast as they are answered. Measured:

- ``reads``: Modbus read requests answered per second over ``BENCH_SCADA_WINDOW_S`` (goal >= 4,000),
  and registers per second; the controller's CPU share over that window (user + system seconds per
  wall second, 1.0 = one core), the simulator's beside it;
- ``estop_modbus``: a write of 1 to the e-stop coil -> the devices' latches (the simulated PLC's and
  motor controller's own truth log): ``stopped`` is the later of the two, "auger and drive
  stopped", p50/p99 (goal p99 <= 10 ms);
- ``estop_zenoh``: the same from the query `fishfarm override estop` sends (``override/estop`` over
  Zenoh; the CLI's own interpreter start-up, ~0.3 s, is not the controller's and is left out);
  both while the 4 pollers keep polling. After each e-stop the reset coil is written and the
  bench waits for the robot to get going again.

Run: ``.venv/bin/python bench/bench_scada.py``; prints one JSON object.
"""
from __future__ import annotations

import json
import os
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_estop import Truth, figures, pct  # noqa: E402
from controller.bus import Bus  # noqa: E402
from hil_tests.farm import HilFarm  # noqa: E402

N = int(os.environ.get("BENCH_SCADA_N", "40"))            # e-stops of each kind
SPEED = float(os.environ.get("BENCH_SCADA_SPEED", "5"))
WINDOW_S = float(os.environ.get("BENCH_SCADA_WINDOW_S", "10"))
TANKS = 100
POLLERS = int(os.environ.get("BENCH_SCADA_POLLERS", "4"))   # 0: the e-stops without SCADA load, to compare
# during the e-stops the pollers are paced at this many requests/s together (the goal's load, a
# little over): four unpaced pollers on this 2-core machine are CPU the controller would not share
# with a SCADA on another host. 0: unpaced, as in the throughput window.
ESTOP_LOAD = float(os.environ.get("BENCH_SCADA_ESTOP_LOAD", "4400"))
GOAL_READS_S = 4000
GOAL_MS = 10.0
ESTOP_STATE, HOMING_STATE = 7, 2     # feeder.state codes (README, the register map)

POLLER = r"""
import socket, struct, sys, time
port, tanks, rate = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
s = socket.create_connection(("127.0.0.1", port))
s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
count, tid, last = 0, 0, time.monotonic()
slot = last
print("polling", flush=True)
def recv(n):
    buf = b""
    while len(buf) < n:
        chunk = s.recv(n - len(buf))
        if not chunk:
            raise SystemExit("closed")
        buf += chunk
    return buf
while True:
    if rate > 0:
        slot = max(slot + 1.0 / rate, time.monotonic() - 0.05)   # behind: catch up, a burst at most
        time.sleep(max(0.0, slot - time.monotonic()))
    tid = (tid + 1) & 0xFFFF
    s.sendall(struct.pack(">HHHBBHH", tid, 0, 6, 1, 4, 100 + 20 * (count % tanks), 20))
    _, _, length, _ = struct.unpack(">HHHB", recv(7))
    data = recv(length - 1)
    assert data[0] == 4 and data[1] == 40, data[:2]
    count += 1
    if time.monotonic() - last >= 0.25:
        last = time.monotonic()
        print(count, flush=True)
"""


class Modbus:
    """The bench's own SCADA connection (raw MBAP: nothing between the write and the wire)."""

    def __init__(self, port: int):
        self.s = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.tid = 0

    def call(self, pdu: bytes) -> bytes:
        self.tid = (self.tid + 1) & 0xFFFF
        self.s.sendall(struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, 1) + pdu)
        head = b""
        while len(head) < 7:
            head += self.s.recv(7 - len(head))
        length = struct.unpack(">HHHB", head)[2]
        data = b""
        while len(data) < length - 1:
            data += self.s.recv(length - 1 - len(data))
        return data

    def coil(self, address: int) -> bytes:
        return self.call(struct.pack(">BHH", 5, address, 0xFF00))

    def feeder_state(self) -> int:
        return struct.unpack(">H", self.call(struct.pack(">BHH", 4, 10, 1))[2:4])[0]


def cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Pollers:
    def __init__(self, port: int, rate_each: float = 0.0):
        self.procs = [subprocess.Popen([sys.executable, "-c", POLLER, str(port), str(TANKS), str(rate_each)],
                                       stdout=subprocess.PIPE, text=True) for _ in range(POLLERS)]
        for p in self.procs:
            assert p.stdout.readline().strip() == "polling"
        self.counts = [0] * POLLERS
        import threading
        for i, p in enumerate(self.procs):
            threading.Thread(target=self._follow, args=(i, p), daemon=True).start()

    def _follow(self, i, proc) -> None:
        for line in proc.stdout:
            self.counts[i] = int(line)

    def total(self) -> int:
        return sum(self.counts)

    def alive(self) -> bool:
        return all(p.poll() is None for p in self.procs)

    def stop(self) -> None:
        for p in self.procs:
            p.kill()
            p.wait()


def estop_once(kind: str, mb: Modbus, bus: Bus, truth: Truth) -> tuple[float | None, float | None, float | None]:
    t0 = time.time()
    if kind == "modbus":
        reply = mb.coil(0)
        assert reply[0] == 5, f"e-stop coil refused: {reply!r}"
    else:
        answers = list(bus.session.get(bus.key("override/estop"),
                                       payload=b'{"operator":"bench","reason":"latency"}', timeout=5.0))
        assert answers, "no reply to override/estop"
    d, r = truth.first_after("dispenser", t0), truth.first_after("rail", t0)
    if d is None or r is None:
        return None, None, None
    return 1000 * (d - t0), 1000 * (r - t0), 1000 * (max(d, r) - t0)


def main() -> dict:
    tanks = [{"id": f"T{i}", "stock": 4000, "mean_weight_g": 40.0, "position_m": 2.0 + 0.8 * i,
              "sensors": [f"T{i}-a", f"T{i}-b"]} for i in range(1, TANKS + 1)]
    fish = {"ration_pct_day": 20.0, "hunger_threshold_g": 10.0, "initial_hunger": 2.0, "rate_hz": [1.0, 2.0],
            "duration_s": [600.0, 600.0], "rest_s": 0.0}
    overrides = {"tanks": tanks, "feeding": {"portion_g": 20.0}, "scada": {"max_connections": 16},
                 "sim": {"rail": {"rail_length_m": 2.0 + 0.8 * TANKS + 5.0}, "fish": fish}}
    farm = HilFarm(Path(tempfile.mkdtemp(prefix="bench-scada-")), speed=SPEED, overrides=overrides)
    pollers = None
    out: dict = {"tanks": TANKS, "speed": SPEED, "pollers": POLLERS, "load_before": os.getloadavg()[0]}
    try:
        farm.start_sim()
        farm.start_controller()
        farm.wait_controller_up()
        port, endpoint = farm.scada_port, f"tcp/127.0.0.1:{farm.zenoh_port}"
        time.sleep(3.0)                                          # the robot gets going
        pollers = Pollers(port)
        time.sleep(1.0)
        n0, c0, s0, t0 = pollers.total(), cpu_s(farm.ctl_proc.pid), cpu_s(farm.sim_proc.pid), time.monotonic()
        time.sleep(WINDOW_S)
        n1, c1, s1, t1 = pollers.total(), cpu_s(farm.ctl_proc.pid), cpu_s(farm.sim_proc.pid), time.monotonic()
        assert pollers.alive(), "a poller lost its connection"
        wall = t1 - t0
        out["reads"] = {"requests_per_s": round((n1 - n0) / wall), "registers_per_s": round(20 * (n1 - n0) / wall),
                        "window_s": round(wall, 1), "controller_cpu_share": round((c1 - c0) / wall, 2),
                        "sim_cpu_share": round((s1 - s0) / wall, 2), "goal_requests_per_s": GOAL_READS_S,
                        "goal_met": (n1 - n0) / wall >= GOAL_READS_S}
        if ESTOP_LOAD > 0 and POLLERS:                            # the goal's load, paced
            pollers.stop()
            pollers = Pollers(port, ESTOP_LOAD / POLLERS)
            time.sleep(1.0)
        n1, t_e0 = pollers.total(), time.monotonic()
        truth = Truth(farm.truth_path)
        mb = Modbus(port)
        samples = {"modbus": ([], [], []), "zenoh": ([], [], [])}
        missing = {"modbus": 0, "zenoh": 0}
        states = {}
        with Bus.client(endpoint, site=farm.config.get("site", "demo"), timeout_s=5.0) as bus:
            for i in range(2 * N):
                kind = ("modbus", "zenoh")[i % 2]
                state = mb.feeder_state()
                states[state] = states.get(state, 0) + 1
                got = estop_once(kind, mb, bus, truth)
                if got[0] is None:
                    missing[kind] += 1
                else:
                    for series, v in zip(samples[kind], got, strict=True):
                        series.append(v)
                time.sleep(0.2)
                mb.coil(1)                                       # reset, over Modbus
                deadline = time.time() + 20.0
                while mb.feeder_state() in (ESTOP_STATE, HOMING_STATE) and time.time() < deadline:
                    time.sleep(0.05)
                time.sleep(0.3 + 0.5 * (i % 3))                  # let it get moving again
        n2 = pollers.total()
        assert pollers.alive(), "a poller lost its connection during the e-stops"
        out["reads_during_estops"] = {"requests": n2 - n1,
                                      "requests_per_s": round((n2 - n1) / (time.monotonic() - t_e0)),
                                      "paced_at": ESTOP_LOAD or None}
        for kind in ("modbus", "zenoh"):
            disp, drive, stopped = samples[kind]
            out[f"estop_{kind}"] = ({"samples": len(stopped), "missing": missing[kind],
                                     "stopped": {**figures(stopped), "p90_ms": round(pct(stopped, 0.9), 2)},
                                     "dispenser": figures(disp), "drive": figures(drive), "goal_p99_ms": GOAL_MS,
                                     "goal_met": pct(stopped, 0.99) <= GOAL_MS and missing[kind] == 0}
                                    if stopped else {"samples": 0, "missing": missing[kind], "goal_met": False})
        out["feeder_states_at_estop"] = {str(k): v for k, v in sorted(states.items())}
        farm.check_alive()
    finally:
        if pollers is not None:
            pollers.stop()
        farm.stop()
    out["load_after"] = os.getloadavg()[0]
    return out


if __name__ == "__main__":
    from bench import no_arguments

    no_arguments(__doc__)
    print(json.dumps(main(), indent=2))
