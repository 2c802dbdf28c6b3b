"""A serial port is one process's at a time: a driver opening a port another driver holds is
refused (LinkDown naming the lock) and the holder's traffic goes on untouched. Under a parallel
test run, and on a farm, a driver retrying the path of a device that went away can meet another
device's pseudo-terminal there (lowest numbers first): before, it read half of that one's bytes."""
from __future__ import annotations

import asyncio
import os
import tty

import pytest

from devices import serial_lock
from devices.clock import ManualClock, ScaledClock
from devices.contacts.serial_hub import Config as HubConfig
from devices.contacts.serial_hub import SerialContactHub
from devices.errors import LinkDown
from tests.devices.test_rail_can import SPEED, heard, rig


@pytest.fixture
def pty_path():
    master, slave = os.openpty()
    tty.setraw(slave)
    yield os.ttyname(slave)
    os.close(master)
    os.close(slave)


def hub(port: str) -> SerialContactHub:
    return SerialContactHub("contacts", HubConfig(kind="contacts", driver="serial", port=port, silence_timeout_s=5.0),
                            ManualClock())


def test_a_held_port_is_refused_until_released(pty_path):
    fd = serial_lock.hold(pty_path)
    with pytest.raises(serial_lock.PortInUse, match="in use by another process"):
        serial_lock.hold(pty_path)            # flock: a second open file is refused, here or elsewhere
    serial_lock.release(fd)
    serial_lock.release(serial_lock.hold(pty_path))
    assert serial_lock.hold("socket://localhost:1") is None and serial_lock.hold("/dev/no-such-port") is None


def test_a_contact_hub_driver_is_refused_a_port_the_rail_drive_holds_and_the_drive_goes_on():
    async def main():
        async with rig("slcan", ScaledClock.starting(SPEED)) as (drive, _motor, port):
            intruder = hub(port.port)
            with pytest.raises(LinkDown, match="lock"):
                await intruder.open()
            await intruder.close()
            drive._latest = None                          # a fresh status frame after the refusal
            await heard(drive)
            assert drive.status() is not None
        again = hub(port.port)                            # closed, the drive let the port go
        with pytest.raises(LinkDown, match="cannot open"):   # (the adapter is unplugged by now)
            await again.open()
    asyncio.run(asyncio.wait_for(main(), 30))


def test_the_rail_drive_is_refused_a_port_a_contact_hub_driver_holds(pty_path):
    from devices.rail.can_drive import CanRailDrive
    from tests.devices.test_rail_can import drive_config

    async def main():
        holder = hub(pty_path)
        await holder.open()
        try:
            drive = CanRailDrive("rail", drive_config(pty_path, "slcan"), ScaledClock.starting(SPEED))
            with pytest.raises(LinkDown, match="in use by another process"):
                await drive.open()
            await drive.close()
        finally:
            await holder.close()
    asyncio.run(asyncio.wait_for(main(), 30))
