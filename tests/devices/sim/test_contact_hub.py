"""The simulated contact hub's heartbeat, read raw from its pseudo-terminal."""
from __future__ import annotations

import asyncio
import os
import statistics

from devices.clock import ManualClock, ScaledClock
from devices.contacts.serial_hub import LINE
from devices.sim.contact_hub import SimContactHub


async def heartbeats(hub: SimContactHub, n: int, advance=None, wall_s: float = 5.0):
    """Farm stamps and wall arrival times of the first ``n`` heartbeat lines the hub writes
    (``advance(stamp)`` after each)."""
    loop = asyncio.get_running_loop()
    fd = os.open(hub.port, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    arrived = asyncio.Event()
    loop.add_reader(fd, arrived.set)
    stamps: list[float] = []
    walls: list[float] = []
    partial = b""
    try:
        while len(stamps) < n:
            await asyncio.wait_for(arrived.wait(), wall_s)
            arrived.clear()
            try:
                *lines, partial = (partial + os.read(fd, 65536)).split(b"\n")
            except BlockingIOError:
                continue
            for line in lines:
                m = LINE.fullmatch(line.rstrip(b"\r"))
                if m is not None and m[5] is not None:
                    stamps.append(int(m[6]) / 1000)
                    walls.append(loop.time())
                    if advance is not None:
                        advance(stamps[-1])
    finally:
        loop.remove_reader(fd)
        os.close(fd)
    return stamps[:n], walls[:n]


def test_heartbeat_comes_at_least_once_a_farm_second_in_fast_simulation():
    async def main():
        clock = ScaledClock.starting(60.0, 1_780_000_000.0)       # 0.25 s of wall = 15 farm s
        hub = SimContactHub([], clock)
        await hub.start()
        try:
            return await heartbeats(hub, 15)
        finally:
            await hub.stop()
    stamps, _ = asyncio.run(main())
    gaps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
    assert statistics.median(gaps) <= 1.0 and all(g > 0 for g in gaps)


def test_heartbeat_follows_a_manual_clock_and_an_explicit_period_is_honoured():
    async def main(params, steps):
        clock = ManualClock(t=1000.0)
        hub = SimContactHub([], clock, params)
        main.started = asyncio.get_running_loop().time()
        await hub.start()
        try:
            # farm time jumps 50 s after each beat of the time it stands at; a wall-clock heartbeat
            # repeating it (this process stalled past heartbeat_s on a loaded machine) moves nothing
            return hub, await heartbeats(hub, steps, advance=lambda stamp: clock.advance(50.0)
                                         if stamp == clock.now() else None)
        finally:
            await hub.stop()
    # the hub's next poll reports each jump, without waiting for its wall-clock heartbeat (which only
    # keeps a frozen clock's line alive): every farm time in turn, none skipped, few repeated
    hub, (stamps, walls) = asyncio.run(main({}, 8))
    distinct = list(dict.fromkeys(stamps))
    assert distinct == [1000.0 + 50.0 * i for i in range(len(distinct))] and stamps == sorted(stamps)
    assert len(distinct) >= 6, stamps
    assert statistics.median(b - a for a, b in zip(walls, walls[1:], strict=False)) < hub.heartbeat_s / 4
    # an explicit period is the only rule: beats every heartbeat_s of wall, farm time or not
    hub, (stamps, walls) = asyncio.run(main({"heartbeat_s": 0.05}, 4))
    assert hub.heartbeat_s == 0.05 and hub.heartbeat_farm_s is None
    # the 4th beat cannot arrive before three periods have passed (gaps between arrivals could not
    # say so: on a loaded machine the beats were read two at a time, 0 s apart)
    assert walls[-1] - main.started >= 3 * 0.05 * 0.9
