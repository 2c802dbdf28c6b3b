"""The contact hub's line health in the status snapshot: rejected and missing lines, and sensors
nobody configured, counted across the link's reconnections."""
from __future__ import annotations

import asyncio
import os
import tty

from controller import app
from controller.status import contact_lines
from devices.contacts.serial_hub import checksum
from tests.controller.test_shutdown import in_process


def line(body: bytes, good: bool = True) -> bytes:
    return b"$" + body + b"*%02X\r\n" % (checksum(body) ^ (0 if good else 0x5A))


def test_status_counts_the_hubs_bad_and_missing_lines_across_reconnections(tmp_path, monkeypatch):
    master, slave = os.openpty()
    tty.setraw(slave)
    controller, _ = in_process(tmp_path, monkeypatch)
    section = {**controller.cfg.devices["contacts"], "port": os.ttyname(slave)}
    controller.devices["contacts"] = app.build_device("contacts", section, controller.clock, controller.cfg.path)
    controller.contacts = controller.devices["contacts"]
    t_ms = int(controller.clock.now() * 1000)

    async def main():
        hub = controller.contacts
        await hub.open()
        os.write(master, line(b"C,1,T1-a,%d" % t_ms) + line(b"C,2,T1-a,%d" % t_ms, good=False)
                 + b"garbage\r\n" + line(b"C,5,ghost,%d" % t_ms) + line(b"H,6,%d" % t_ms))
        got = []
        while len(got) < 2:
            got += await asyncio.wait_for(hub.read(), 5)
        assert [c.sensor for c in got] == ["T1-a", "ghost"]
        controller.unknown_sensors.add("ghost")          # as the contacts loop notes it
        first = contact_lines(controller)
        await controller._reopen(hub)                    # the link lost and opened anew
        assert controller.contacts is not hub
        os.write(master, line(b"C,7,T1-b,%d" % t_ms) + b"$C,8*00\r\n" + line(b"C,10,T1-b,%d" % t_ms))
        got = []
        while len(got) < 2:
            got += await asyncio.wait_for(controller.contacts.read(), 5)
        await controller.contacts.close()
        return first, contact_lines(controller)

    first, second = asyncio.run(asyncio.wait_for(main(), 30))
    controller.store.close()
    os.close(master)
    os.close(slave)
    # seq 2 (bad checksum) and the garbage rejected; 2, 3 and 4 missing before 5
    assert first == {"device": "contacts", "unknown_sensors": ["ghost"], "malformed": 2, "lost": 3}
    # the fresh link's own: one more rejected, 8 and 9 missing (its first line sets no gap)
    assert second == {"device": "contacts", "unknown_sensors": ["ghost"], "malformed": 3, "lost": 5}
