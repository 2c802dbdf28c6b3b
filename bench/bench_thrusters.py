"""The thrusters' serial driver against the simulated controller on a pty: how long a drive takes
to be accepted, and how long ``trip_estop`` takes to write the latch and read it back.

- ``drive_ms``: ``await drive()`` until the reply (status first, then the reply);
- ``trip_estop_ms``: ``trip_estop()`` from a plain thread (as the e-stop lane calls it) until a
  status showing the latch, each after a reset; ``..._busy_ms`` the same while the loop sends
  drives back to back (it must not wait behind them).

Run: ``.venv/bin/python bench/bench_thrusters.py``; prints one JSON object. Env: ``BENCH_THRUSTERS_N``.
"""
from __future__ import annotations

import asyncio
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from devices.clock import ScaledClock  # noqa: E402
from devices.errors import DeviceError  # noqa: E402
from devices.sim.thrusters import SimThrusters  # noqa: E402
from devices.thrusters.serial_thrusters import Config, SerialThrusters  # noqa: E402


def stats(xs) -> dict:
    a = np.array(xs) * 1000
    return {"p50": round(float(np.percentile(a, 50)), 3), "p99": round(float(np.percentile(a, 99)), 3),
            "max": round(float(a.max()), 3)}


async def trips(dev, n: int) -> list[float]:
    out = []
    for _ in range(n):
        await dev.reset_estop()
        t0 = time.perf_counter()
        st = await asyncio.to_thread(dev.trip_estop)
        out.append(time.perf_counter() - t0)
        assert st.estop
    return out


async def main() -> dict:
    n = int(os.environ.get("BENCH_THRUSTERS_N", "300"))
    clock = ScaledClock.real()
    sim = SimThrusters(clock, {"watchdog_s": 60})
    await sim.start()
    dev = SerialThrusters("thrusters", Config(kind="thrusters", driver="serial", port=sim.port), clock)
    await dev.open()
    drives = []
    for i in range(n):
        t0 = time.perf_counter()
        await dev.drive((i % 10) / 10, -(i % 10) / 10)
        drives.append(time.perf_counter() - t0)
    idle = await trips(dev, n)

    stop = asyncio.Event()

    async def flood():
        while not stop.is_set():
            try:
                await dev.drive(0.5, 0.5)
            except DeviceError:            # refused while latched: that is the point
                await asyncio.sleep(0)
    task = asyncio.create_task(flood())
    busy = await trips(dev, n)
    stop.set()
    await task
    await dev.close()
    await sim.stop()
    return {"n": n, "drive_ms": stats(drives), "trip_estop_ms": stats(idle), "trip_estop_busy_ms": stats(busy),
            "malformed": dev.malformed, "load": os.getloadavg()[0]}


if __name__ == "__main__":
    from bench import no_arguments

    no_arguments(__doc__)
    print(json.dumps(asyncio.run(main())))
