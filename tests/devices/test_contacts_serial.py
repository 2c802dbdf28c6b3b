"""The contact hub's serial driver against the simulated hub, on a real pseudo-terminal."""
from __future__ import annotations

import asyncio
import heapq
import os
import time
import tty

import numpy as np
import pytest
import serial

from controller.config import load_config
from devices.clock import ManualClock
from devices.contacts.serial_hub import Config, SerialContactHub, checksum, contact_line, heartbeat_line
from devices.errors import LinkDown
from devices.sim import contact_streams as cs
from devices.sim.contact_hub import SimContactHub
from devices.sim.fish import SimFishParams, SimTank
from devices.sim.truth import TruthLog

SILENCE_S = 0.3            # wall seconds without a line before the driver calls the link down


def driver(port, clock, timeout=1.0):
    return SerialContactHub("contacts", Config(kind="contacts", driver="serial", port=port,
                                               silence_timeout_s=timeout), clock)


async def read_n(dev, n, timeout=10.0):
    got = []
    while len(got) < n:
        got += await asyncio.wait_for(dev.read(), timeout)
    return got


def stream(seed=1, t0=1000.0):
    rng = np.random.default_rng(seed)
    return cs.tank_day(rng, "T1", ("T1-a", "T1-b"), t0, days=0.02, turbulence_hz=0.3, bursts_per_hour=200)


def test_line_format_is_nmea_style():
    line = contact_line(7, "T1-a", 1780000000.1234)
    assert line == b"$C,7,T1-a,1780000000123*%02X\r\n" % checksum(b"C,7,T1-a,1780000000123")
    assert heartbeat_line(65537, 1.0).startswith(b"$H,1,1000*")


def test_contacts_arrive_with_their_stamps_and_noise_is_counted():
    async def main():
        clock = ManualClock(t=1000.0)
        st = stream()
        hub = SimContactHub([cs.Replay(st)], clock, {"noise_per_s": 400, "seed": 3})
        await hub.start()
        dev = driver(hub.port, clock)
        await dev.open()
        got = []
        for _ in range(40):                     # 50 s of farm time per step: bursts, not floods
            clock.advance(50.0)
            got += await dev.read() if len(got) < int(np.searchsorted(st.t, clock.now())) else []
        got += await read_n(dev, len(st) - len(got))
        await asyncio.sleep(0.05)
        await hub.stop()
        await dev.close()
        return st, got, dev, hub
    st, got, dev, hub = asyncio.run(main())
    assert [c.sensor for c in got] == st.sensor.tolist()
    assert np.array_equal([c.t for c in got], np.round(st.t * 1000) / 1000)
    assert hub.noise > 0 and hub.dropped == 0
    assert dev.malformed == hub.noise            # every corrupt line rejected, none let through
    assert dev.lost == hub.noise                 # their sequence numbers are missing


def test_lines_waiting_in_the_port_after_a_stall_are_not_silence():
    """The process stalls (the VM descheduled it) past the silence limit while a line waits in the
    kernel: the driver looks at the port before calling it silent."""
    async def main():
        master, slave = os.openpty()
        tty.setraw(slave)
        dev = driver(os.ttyname(slave), ManualClock(), timeout=SILENCE_S)
        await dev.open()
        os.write(master, contact_line(0, "T1-a", 2.0))
        time.sleep(SILENCE_S * 1.5)                # the loop is held: its reader has not run
        (c,) = await asyncio.wait_for(dev.read(), 5)
        with pytest.raises(LinkDown, match="silent"):   # and a port that is silent still is
            await dev.read()
        await dev.close()
        os.close(master)
        os.close(slave)
        return c
    assert asyncio.run(main()).sensor == "T1-a"


def test_stream_time_passes_contacts_only_once_they_are_read():
    """``stream_t`` is what time-driven judgements go by: parsed past contacts that wait for
    read(), it would let the filter close their bins before it is given them."""
    async def main():
        master, slave = os.openpty()
        tty.setraw(slave)
        dev = driver(os.ttyname(slave), ManualClock(), timeout=5.0)
        await dev.open()
        seen = []

        async def parsed(n_lines):
            while dev.lines < n_lines:
                await asyncio.sleep(0.005)
            seen.append(dev.stream_t)
        os.write(master, heartbeat_line(0, 900.0))
        await asyncio.wait_for(parsed(1), 5)                 # heartbeats alone: heard at once
        os.write(master, contact_line(1, "T1-a", 1000.0) + contact_line(2, "T1-b", 1100.0)
                 + heartbeat_line(3, 1300.0))
        await asyncio.wait_for(parsed(4), 5)                 # contacts waiting: not past them
        got = await asyncio.wait_for(dev.read(), 5)
        seen.append(dev.stream_t)                            # handed out: up to the newest stamp
        os.write(master, heartbeat_line(4, 1400.0))
        await asyncio.wait_for(parsed(5), 5)
        await dev.close()
        os.close(master)
        os.close(slave)
        return seen, got
    seen, got = asyncio.run(main())
    assert [c.t for c in got] == [1000.0, 1100.0]
    assert seen == [900.0, 900.0, 1300.0, 1400.0]


def test_silence_is_link_down_and_a_fresh_driver_reopens():
    async def main():
        master, slave = os.openpty()
        tty.setraw(slave)
        port = os.ttyname(slave)
        clock = ManualClock()
        dev = driver(port, clock, timeout=SILENCE_S)
        await dev.open()
        loop = asyncio.get_running_loop()
        t = loop.time()                       # before the last line: silence counts from it
        os.write(master, heartbeat_line(0, 1.0) + contact_line(1, "T1-a", 2.0))
        (c,) = await read_n(dev, 1)
        with pytest.raises(LinkDown, match="silent"):
            await dev.read()
        waited = loop.time() - t
        await dev.close()
        await dev.close()                                    # safe twice
        again = driver(port, clock, timeout=SILENCE_S)
        await again.open()
        os.write(master, contact_line(2, "T1-b", 3.0) + contact_line(9, "T1-b", 4.0))
        got = await read_n(again, 2)
        await again.close()
        os.close(master)
        os.close(slave)
        return c, waited, got, again.lost
    c, waited, got, lost = asyncio.run(main())
    assert (c.t, c.sensor) == (2.0, "T1-a")
    assert SILENCE_S <= waited < 3 * SILENCE_S                # not before the timeout, nor long after
    assert [x.t for x in got] == [3.0, 4.0] and lost == 6


def test_port_vanishing_is_link_down():
    async def main():
        clock = ManualClock()
        hub = SimContactHub([cs.Replay(stream(2))], clock)
        await hub.start()
        dev = driver(hub.port, clock, timeout=5.0)
        await dev.open()
        await hub.stop()
        with pytest.raises(LinkDown, match="port gone|end of file"):
            await asyncio.wait_for(dev.read(), 3)
        await dev.close()
    asyncio.run(main())


def test_cannot_open_a_missing_port():
    async def main():
        with pytest.raises(LinkDown, match="cannot open"):
            await driver("/dev/nonexistent-hub", ManualClock()).open()
    asyncio.run(main())


def test_a_url_without_a_file_descriptor_is_link_down_and_the_port_is_released(monkeypatch):
    opened = []

    def spy(*args, **kwargs):
        opened.append(real(*args, **kwargs))
        return opened[-1]
    real = serial.serial_for_url
    monkeypatch.setattr(serial, "serial_for_url", spy)

    with pytest.raises(ValueError, match="loop:// has no file descriptor"):
        driver("loop://", ManualClock())                          # refused with the config, first
    section = Config.model_construct(kind="contacts", driver="serial", port="loop://", baudrate=115200,
                                     silence_timeout_s=1.0)      # and should one get past it

    async def main():
        dev = SerialContactHub("contacts", section, ManualClock())
        with pytest.raises(LinkDown, match="loop://") as exc:
            await dev.open()
        await dev.close()
        return exc.value
    err = asyncio.run(main())
    assert "file descriptor" in err.text
    assert len(opened) == 1 and not opened[0].is_open         # released, not leaked


class Polled:
    """A tank that remembers the farm times the hub polled it at, so a twin can be replayed."""

    def __init__(self, tank):
        self.tank = tank
        self.asked: list[float] = []

    def contacts_until(self, t):
        self.asked.append(t)
        return self.tank.contacts_until(t)


def demo_tanks(truth=None):
    cfg = load_config("config/farm.toml")
    params = SimFishParams(bursts_per_hour=20.0, initial_hunger=1.0)
    return [SimTank(t, params, np.random.default_rng(i), truth) for i, t in enumerate(cfg.tanks)]


async def read_past(dev, farm_t: float, got: list, wall_s: float = 10.0) -> None:
    """Read until the driver has seen a line stamped after ``farm_t``: every line of the hub's
    polls up to ``farm_t`` came before it on the line, so all their contacts are in ``got``."""
    deadline = asyncio.get_running_loop().time() + wall_s
    while dev.stream_t is None or dev.stream_t <= farm_t + 0.002:    # stamps are rounded to 1 ms
        assert asyncio.get_running_loop().time() < deadline, "the hub's stream stopped"
        try:
            got += await asyncio.wait_for(dev.read(), 0.1)
        except TimeoutError:
            pass                                                     # heartbeats only: look again


def test_sim_tanks_reach_the_driver_whole_and_in_order():
    """The demo farm's tanks through the pty, a quarter of a farm hour in 5-s steps taken as fast as
    the line carries them: every contact the tanks made arrives. The clock is a manual one: under a
    ScaledClock at 600x a stall of the VM piled ~600 farm seconds into one write and the pty's buffer
    overflowed (the hub dropped 1,665 lines, as a real UART would) — the line's throughput is a
    benchmark's matter, not this test's."""
    async def main():
        clock = ManualClock(1_780_000_000.0)
        truth = TruthLog(None)
        tanks = [Polled(t) for t in demo_tanks(truth)]
        hub = SimContactHub(tanks, clock)
        await hub.start()
        dev = driver(hub.port, clock, timeout=5.0)
        await dev.open()
        got = []
        for _ in range(180):
            clock.advance(5.0)
            await read_past(dev, clock.now() - 0.01, got)    # the poll's heartbeat is stamped now
        polls = len(tanks[0].asked)      # the last step's heartbeat came after all its contacts
        await hub.stop()
        await dev.close()
        return got, hub, dev, truth, tanks, polls
    got, hub, dev, truth, tanks, polls = asyncio.run(main())
    assert hub.dropped == 0 and dev.lost == 0 and dev.malformed == 0
    ts = [c.t for c in got]
    assert ts == sorted(ts) and len(got) > 100
    assert any(r["kind"] == "episode_start" for r in truth.records)
    # an identically seeded twin farm, polled at the same farm times, made exactly these contacts
    twins = demo_tanks()
    made, upto_window = [], 0
    for i, t in enumerate(tanks[0].asked):
        assert all(tank.asked[i] == t for tank in tanks)
        made += [(round(tc * 1000) / 1000, sensor)
                 for tc, sensor in heapq.merge(*(twin.contacts_until(t) for twin in twins))]
        upto_window = len(made) if i == polls - 1 else upto_window
    assert len({sensor for _, sensor in made[:upto_window]}) > 8        # most tanks spoke
    assert len(got) >= upto_window
    assert [(c.t, c.sensor) for c in got] == made[:len(got)]


def test_a_sequence_number_beyond_the_protocol_s_16_bits_is_a_malformed_line():
    """``seq`` is 0..65535 (serial_hub.py's protocol): 99999 was taken as a valid contact."""
    dev = SerialContactHub("contacts", Config(kind="contacts", driver="serial", port="/dev/null"), None)

    def line(kind: str, seq: int) -> bytes:
        body = f"C,{seq},T1-a,1780000000000".encode() if kind == "C" else f"H,{seq},1780000000000".encode()
        return b"$" + body + b"*%02X" % checksum(body)
    dev._parse([line("C", 65535), line("C", 65536), line("H", 99999), line("C", 0)])
    assert (dev.lines, dev.malformed, [c.sensor for c in dev._batch]) == (2, 2, ["T1-a", "T1-a"])


def test_the_first_line_heard_after_opening_returns_even_a_heartbeat():
    """The controller clears the hub's loss alarm when a read returns: after a reconnection it
    stood until a fish bumped a sensor (at night, for hours), heartbeats arriving all along."""
    async def main():
        master, slave = os.openpty()
        tty.setraw(slave)
        dev = driver(os.ttyname(slave), ManualClock())
        await dev.open()
        try:
            os.write(master, heartbeat_line(1, 1000.0))
            assert await asyncio.wait_for(dev.read(), 5) == []            # the line is heard
            os.write(master, heartbeat_line(2, 1001.0))
            with pytest.raises(asyncio.TimeoutError):                     # then contacts only
                await asyncio.wait_for(dev.read(), 0.3)
            os.write(master, contact_line(3, "T1-a", 1002.0))
            assert [c.sensor for c in await asyncio.wait_for(dev.read(), 5)] == ["T1-a"]
        finally:
            await dev.close()
            os.close(master)
            os.close(slave)
    asyncio.run(main())
