"""The rail's CAN adapter unplugged and plugged back while the robot waits: the robot opens a fresh
driver on the same channel and feeds again (it stayed in fault until the controller restarted)."""
from __future__ import annotations

import asyncio

from devices.rail.can_drive import CanRailDrive
from devices.rail.can_drive import Config as RailConfig
from devices.sim.rail import SimRailMotor, SimRailParams
from devices.sim.slcan_adapter import SlcanAdapter
from tests.controller.feeding.rig import Rig


class SlcanRig(Rig):
    """The rig with its drive behind an slcan adapter on a pseudo-terminal, named by a stable link
    (as udev names a USB adapter), and the controller's way of reopening a lost device."""

    async def start(self, run: bool = True, wrap=None):
        self.adapter = SlcanAdapter()
        await self.motor.start(self.adapter)
        self.link.symlink_to(self.adapter.port)
        self.rail = CanRailDrive("rail", RailConfig(kind="rail", driver="can", interface="slcan",
                                                    channel=str(self.link)), self.clock)
        await super().start(run, wrap)

    def new_robot(self):
        robot = super().new_robot()
        robot.reopen = self.reopen
        return robot

    async def reopen(self, device):
        """As the controller's: the old driver closed, a new one on its section opened, the lane's latch moved."""
        await device.close()
        fresh = CanRailDrive(device.name, device.config, self.clock)
        await fresh.open()
        self.robot.lane.replace_device(device, fresh)
        self.reopened.append(fresh)
        return fresh


def test_a_rail_adapter_unplugged_and_plugged_back_is_reopened_and_feeding_goes_on(tmp_path):
    async def main():
        r = SlcanRig(tmp_path, 100.0, {}, {}, {})
        r.link, r.reopened = tmp_path / "ttyRAIL", []
        await r.start()
        try:
            await r.until(lambda: r.robot.state == "idle", what="homed")
            await r.motor.stop()                                  # unplugged: the pty is gone
            await r.until(lambda: r.robot.state == "fault", farm_s=1000.0, what="fault on the lost link")
            r.motor = SimRailMotor(SimRailParams(), r.clock)      # plugged back: a new pty, the same link
            adapter = SlcanAdapter()
            await r.motor.start(adapter)
            r.link.unlink()
            r.link.symlink_to(adapter.port)
            await r.until(lambda: r.robot.state == "idle", farm_s=3000.0, what="back in service")
            assert r.reopened and r.robot.rail is r.reopened[-1]
            served = r.demand("T1")
            await r.until(lambda: r.store.db.execute("SELECT outcome FROM demand WHERE id=?", (served,))
                          .fetchone()[0] == "served", farm_s=600.0, what="served after the replug")
            assert r.robot.lane.latches[0].device is r.robot.rail
        finally:
            await r.stop()
    asyncio.run(asyncio.wait_for(main(), 90))
