"""The thrusters' serial driver on a real pseudo-terminal: against a hand-played device (the exact
bytes both ways) and against the simulated controller (latch, watchdog, replies)."""
from __future__ import annotations

import asyncio
import contextlib
import os
import select
import threading
import time
import tty

import pytest

from devices.clock import ManualClock
from devices.errors import DeviceFault, DeviceTimeout, LinkDown
from devices.sim.thrusters import SimThrusters
from devices.thrusters import EstopLatched, ThrusterState
from devices.thrusters import protocol as p
from devices.thrusters.serial_thrusters import Config, SerialThrusters

from .waits import until

ESTOP_TIMEOUT_S = 0.05         # against a silent line: the bound itself is what is tested
# against the simulated controller the wait ends when the latch shows, so a long bound costs
# nothing; a short one failed whenever a loaded machine held the simulator's answer back 50 ms
SIM_ESTOP_TIMEOUT_S = 2.0
SLACK_S = 1.0                  # a thread's wake-up on a loaded machine, beyond the bound


def driver(port, clock, **kw) -> SerialThrusters:
    cfg = Config(kind="thrusters", driver="serial", port=port,
                 estop_timeout_s=kw.pop("estop_timeout_s", ESTOP_TIMEOUT_S),
                 command_timeout_s=kw.pop("command_timeout_s", 1.0), **kw)
    return SerialThrusters("thrusters", cfg, clock)


class RawPort:
    """The far end of a pty, played by the test: read what the driver wrote, write what a device says."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.buf = b""

    def line(self, timeout=2.0) -> bytes:
        deadline = time.monotonic() + timeout
        while b"\n" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.master], [], [], left)[0]:
                raise AssertionError(f"no line from the driver in {timeout} s (have {self.buf!r})")
            self.buf += os.read(self.master, 4096)
        line, self.buf = self.buf.split(b"\n", 1)
        return line + b"\n"

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def close(self):
        for fd in (self.master, self.slave):
            os.close(fd)


async def in_thread(fn, *args):
    return await asyncio.to_thread(fn, *args)


def test_frames_are_nmea_style_with_per_mille_thrust():
    assert p.drive_line(7, 0.5, -1.0) == b"$D,7,500,-1000*%02X\r\n" % p.checksum(b"D,7,500,-1000")
    assert p.watchdog_line(65537, 0.5).startswith(b"$W,1,500*")
    st = p.Status(3, 1780000000.25, 0.125, -0.5, p.FLAG_ESTOP | p.FLAG_WATCHDOG, 1)
    back = p.parse_status(p.parse(p.status_line(st).rstrip(b"\n")))
    assert back == p.Status(3, 1780000000.25, 0.125, -0.5, 3, 1) and back.estop and back.watchdog
    # line noise: wrong checksum, unknown letter, wrong field count, torn
    good = p.drive_line(1, 0.1, 0.1).rstrip()
    assert p.parse(good) is not None
    assert p.parse(good[:-1] + (b"0" if good[-1:] != b"0" else b"1")) is None
    assert p.parse(p.frame("X,1").rstrip()) is None
    assert p.parse(p.frame("D,1,2").rstrip()) is None
    assert p.parse(good[:8]) is None


def test_driver_writes_the_protocol_and_reads_the_devices_answers():
    """Both directions through a real pty, the device played by hand."""
    async def main():
        port, clock = RawPort(), ManualClock()
        dev = driver(port.path, clock)
        await dev.open()
        task = asyncio.create_task(dev.drive(0.25, -0.75))
        line = await in_thread(port.line)
        assert p.parse(line.rstrip()) == p.Line("D", (1, 250, -750))
        port.write(p.status_line(p.Status(1, 1000.5, 0.1, -0.2, 0, 0)) + p.reply_line(1, p.Result.ACCEPTED))
        await asyncio.wait_for(task, 2)
        assert dev.status() == Thrusters_state(1000.5, 0.1, -0.2)
        for call, want in ((dev.stop(), p.Line("S", (2,))), (dev.set_watchdog(2.5), p.Line("W", (3, 2500))),
                           (dev.reset_estop(), p.Line("R", (4,)))):
            task = asyncio.create_task(call)
            assert p.parse((await in_thread(port.line)).rstrip()) == want
            port.write(p.reply_line(want.fields[0], p.Result.ACCEPTED))
            await asyncio.wait_for(task, 2)
        # refusals become the interface's exceptions
        for result, exc in ((p.Result.FAULT, DeviceFault), (p.Result.ESTOP, EstopLatched)):
            task = asyncio.create_task(dev.drive(0.1, 0.1))
            seq = p.parse((await in_thread(port.line)).rstrip()).fields[0]
            port.write(p.reply_line(seq, result))
            with pytest.raises(exc):
                await asyncio.wait_for(task, 2)
        # fault and watchdog flags come through
        port.write(p.status_line(p.Status(5, 1001.0, 0, 0, p.FLAG_FAULT | p.FLAG_WATCHDOG, p.Fault.STALL)))
        await wait_for_status(dev, lambda s: s.t == 1001.0)
        st = dev.status()
        assert st.watchdog and not st.estop and st.fault == "stall"
        await dev.close()
        port.close()
    asyncio.run(main())


def Thrusters_state(t, left, right, estop=False, watchdog=False, fault=None):
    return ThrusterState(t, left, right, estop, watchdog, fault)


async def wait_for_status(dev, pred, timeout=2.0):
    def matching():
        st = dev.status()
        return st if st is not None and pred(st) else None
    return await until(matching, timeout, f"a status matching (last {dev.status()})")


def test_malformed_lines_are_counted_never_raised():
    async def main():
        port, clock = RawPort(), ManualClock()
        dev = driver(port.path, clock)
        await dev.open()
        noise = [b"garbage\r\n", p.status_line(p.Status(1, 5.0, 0, 0, 0, 0))[:-6] + b"00\r\n",  # bad checksum
                 p.frame("T,1,5000,2000,0,0,0"),           # thrust beyond full
                 p.frame("D,1,0,0"),                       # a command from the device
                 p.frame("A,1"), b"$T,1,2,3*\r\n", b"x" * 300 + b"\r\n"]
        port.write(b"".join(noise) + p.status_line(p.Status(9, 7.0, 0.5, 0.5, 0, 0)))
        st = await wait_for_status(dev, lambda s: s.t == 7.0)
        assert st.left == 0.5
        assert dev.malformed == len(noise)
        await dev.close()
        port.close()
    asyncio.run(main())


def test_trip_estop_is_bounded_when_the_device_is_silent():
    async def main():
        port, clock = RawPort(), ManualClock()
        dev = driver(port.path, clock)
        await dev.open()
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout):
            await in_thread(dev.trip_estop)
        took = time.monotonic() - t0
        assert p.parse((await in_thread(port.line)).rstrip()) == p.Line("E", (0,))   # sent at once
        assert ESTOP_TIMEOUT_S <= took < ESTOP_TIMEOUT_S + SLACK_S
        with pytest.raises(EstopLatched):                   # refused locally, nothing sent
            await dev.drive(0.2, 0.2)
        with pytest.raises(DeviceTimeout):                  # silence is a fault of its own
            await_silence(dev)
        await dev.close()
        await dev.close()                                   # safe twice
        port.close()
    asyncio.run(main())


def await_silence(dev):
    dev._latest_at -= dev.config.status_timeout_s + 1       # as if that long had passed
    dev.status()


def test_trip_estop_does_not_wait_behind_a_command_in_flight():
    """A drive waits for a reply that never comes; the lane's trip goes out meanwhile."""
    async def main():
        port, clock = RawPort(), ManualClock()
        dev = driver(port.path, clock, command_timeout_s=5.0)
        await dev.open()
        drive = asyncio.create_task(dev.drive(1.0, 1.0))
        assert p.parse((await in_thread(port.line)).rstrip()).kind == "D"
        answered = threading.Event()

        def device():       # answers only the E, with the latch shown
            line = port.line()
            assert p.parse(line.rstrip()) == p.Line("E", (0,))
            port.write(p.status_line(p.Status(0, 9.0, 0, 0, p.FLAG_ESTOP, 0)))
            answered.set()
        th = threading.Thread(target=device)
        th.start()
        st = await in_thread(dev.trip_estop)
        th.join()
        assert answered.is_set() and st.estop and dev.estop_seen_since(0.0)
        assert not drive.done()
        drive.cancel()
        await dev.close()
        port.close()
    asyncio.run(main())


# --- against the simulated controller ------------------------------------------------------------
async def with_sim(clock, body, **params):
    sim = SimThrusters(clock, params)
    await sim.start()
    dev = driver(sim.port, clock, estop_timeout_s=SIM_ESTOP_TIMEOUT_S)
    await dev.open()
    try:
        return await body(sim, dev)
    finally:
        await dev.close()
        await sim.stop()


def test_watchdog_stops_the_thrusters_when_drives_stop():
    clock = ManualClock()

    async def body(sim, dev):
        t0 = clock.now()
        for _ in range(10):                              # drives every 0.4 s farm: never trips
            await dev.drive(0.8, 0.6)
            clock.advance(0.4)
        assert sim.twin.watchdog_trips == []
        last = clock.now() - 0.4
        assert sim.thrust(clock.now()) == (0.8, 0.6)
        clock.advance(0.2)                                # 0.6 s since the last drive: past 0.5
        st = await wait_for_status(dev, lambda s: s.watchdog)
        assert sim.twin.watchdog_trips == [pytest.approx(last + 0.5)]
        # from the watchdog's instant both ramp down at 4/s: 0.1 s later 0.4 less
        assert st.left == pytest.approx(0.4) and st.right == pytest.approx(0.2)
        assert sim.thrust(last + 0.5) == pytest.approx((0.8, 0.6))
        clock.advance(1.0)
        st = await wait_for_status(dev, lambda s: s.t >= clock.now() - 0.001)
        assert (st.left, st.right, st.watchdog) == (0.0, 0.0, True)
        await dev.drive(0.3, 0.3)                         # the next drive clears the flag
        assert not dev.status().watchdog
        return t0
    asyncio.run(with_sim(clock, body))


def test_the_watchdog_acts_at_its_instant_however_late_anyone_looks():
    clock = ManualClock()

    async def body(sim, dev):
        await dev.set_watchdog(2.0)
        await dev.drive(-1.0, 1.0)
        t = clock.now()
        clock.advance(3600.0)                             # nobody looked for an hour
        assert sim.thrust(clock.now()) == (0.0, 0.0)
        assert sim.twin.watchdog_trips == [pytest.approx(t + 2.0)]
        assert sim.thrust(t + 1.9) == (-1.0, 1.0)         # the history stays right
        assert sim.thrust(t + 2.125) == pytest.approx((-0.5, 0.5))
    asyncio.run(with_sim(clock, body))


STATES = ("idle", "driving", "ramping", "stopped", "watchdog", "fault", "latched")


async def enter(state, sim, dev, clock):
    if state in ("driving", "ramping", "stopped", "watchdog"):
        await dev.drive(0.9, -0.9)
    if state == "driving":
        clock.advance(0.3)
    if state == "stopped":
        await dev.stop()
    if state == "watchdog":
        clock.advance(0.6)
        await wait_for_status(dev, lambda s: s.watchdog)
    if state == "fault":
        sim.twin.inject_fault(clock.now())
        await wait_for_status(dev, lambda s: s.fault == "overcurrent")
    if state == "latched":
        await in_thread(dev.trip_estop)


@pytest.mark.parametrize("state", STATES)
def test_the_latch_refuses_every_drive_until_reset_from_every_state(state):
    clock = ManualClock()

    async def body(sim, dev):
        await enter(state, sim, dev, clock)
        st = await in_thread(dev.trip_estop)
        assert st.estop and (st.left, st.right) == (0.0, 0.0)      # cut at once, no ramp
        assert sim.thrust(clock.now()) == (0.0, 0.0)
        with pytest.raises(EstopLatched):
            await dev.drive(0.5, 0.5)
        # the device itself refuses too: a second controller on the line that never tripped
        result = sim.twin.handle(p.Line("D", (77, 500, 500)), clock.now())
        assert result is p.Result.ESTOP
        clock.advance(5.0)                                         # time does not release it
        with pytest.raises(EstopLatched):
            await dev.drive(0.5, 0.5)
        await dev.stop()                                           # stop is always accepted
        assert dev.status().estop
        await dev.reset_estop()
        assert not dev.status().estop and dev.status().fault is None
        await dev.drive(0.5, 0.5)
        clock.advance(0.3)                                         # ramped up, watchdog not due
        assert sim.thrust(clock.now()) == (0.5, 0.5)
        assert len(sim.twin.estops) == 1
    asyncio.run(with_sim(clock, body))


def test_the_simulated_controller_counts_malformed_commands_and_answers_bad_values():
    clock = ManualClock()

    async def body(sim, dev):
        port = os.open(sim.port, os.O_RDWR | os.O_NOCTTY)
        os.write(port, b"noise\r\n" + p.frame("D,1,2")[:-5] + b"00\r\n" + p.frame("T,1,2,3,4,5,6"))
        with pytest.raises(ValueError):                            # the interface checks first
            await dev.drive(1.5, 0.0)
        await until(lambda: sim.malformed == 3)
        assert sim.twin.handle(p.Line("D", (40, 1001, 0)), clock.now()) is p.Result.BAD_VALUE
        os.close(port)
        with pytest.raises(ValueError):
            await dev.set_watchdog(0.01)
        assert sim.thrust(clock.now()) == (0.0, 0.0)
        await dev.drive(0.0, 0.0)                                  # still talking
    asyncio.run(with_sim(clock, body))


def test_the_port_vanishing_is_link_down():
    clock = ManualClock()

    async def main():
        sim = SimThrusters(clock)
        await sim.start()
        dev = driver(sim.port, clock)
        await dev.open()
        await dev.drive(0.2, 0.2)
        await sim.stop()
        await until(lambda: dev._link_error is not None)
        with pytest.raises(LinkDown):
            dev.status()
        with pytest.raises(LinkDown):
            await dev.drive(0.2, 0.2)
        with pytest.raises(LinkDown):
            dev.trip_estop()
        await dev.close()
        await dev.close()
    asyncio.run(main())


def test_opening_a_missing_port_is_link_down_and_close_is_safe():
    async def main():
        dev = driver("/dev/nonexistent-thrusters", ManualClock())
        with pytest.raises(LinkDown):
            await dev.open()
        await dev.close()
        await dev.close()
    asyncio.run(main())


def test_watchdog_from_config_is_set_on_open():
    clock = ManualClock()

    async def main():
        sim = SimThrusters(clock)
        await sim.start()
        dev = driver(sim.port, clock, watchdog_s=1.5)
        await dev.open()
        assert sim.twin.watchdog_s == 1.5
        await dev.close()
        await sim.stop()
    asyncio.run(main())


def test_a_silent_controller_board_bounds_trip_estop_and_a_returning_one_latches():
    clock = ManualClock()

    async def body(sim, dev):
        await dev.drive(0.7, 0.7)
        sim.silent = True                                # hears nothing, says nothing
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout):
            await in_thread(dev.trip_estop)
        assert time.monotonic() - t0 < SIM_ESTOP_TIMEOUT_S + SLACK_S
        assert not sim.twin.estop
        with pytest.raises(EstopLatched):                # our own trip holds drives back meanwhile
            await dev.drive(0.7, 0.7)
        sim.silent = False                               # the lane's retry reaches it
        st = await in_thread(dev.trip_estop)
        assert st.estop and sim.twin.estop and sim.thrust(clock.now()) == (0.0, 0.0)
    asyncio.run(with_sim(clock, body))


def test_a_line_that_takes_nothing_is_a_timeout_not_a_lost_link(monkeypatch):
    """The line stops taking bytes (a device not reading, flow control held): trip_estop is
    bounded and says so, and the link is not given up; when the line takes bytes again the same
    driver latches. (A full pipe stands in for the full line: a pty's buffer drains by itself.)"""
    async def main():
        port, clock = RawPort(), ManualClock()
        dev = driver(port.path, clock)
        await dev.open()
        full_r, full_w = os.pipe()
        os.set_blocking(full_w, False)
        with contextlib.suppress(BlockingIOError):
            while True:
                os.write(full_w, b"." * 4096)
        with contextlib.suppress(BlockingIOError):
            while True:
                os.write(full_w, b".")
        line_fd = dev._ser.fileno
        monkeypatch.setattr(dev._ser, "fileno", lambda: full_w)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match="took nothing"):
            await in_thread(dev.trip_estop)
        assert ESTOP_TIMEOUT_S <= time.monotonic() - t0 < ESTOP_TIMEOUT_S + SLACK_S
        assert dev.status() is None                                # not LinkDown
        monkeypatch.setattr(dev._ser, "fileno", line_fd)           # the line takes bytes again

        def device():
            assert p.parse(port.line().rstrip()) == p.Line("E", (0,))
            port.write(p.status_line(p.Status(0, 3.0, 0, 0, p.FLAG_ESTOP, 0)))
        th = threading.Thread(target=device)
        th.start()
        st = await in_thread(dev.trip_estop)
        th.join()
        assert st.estop and dev.status().estop
        await dev.close()
        port.close()
        os.close(full_r)
        os.close(full_w)
    asyncio.run(main())
