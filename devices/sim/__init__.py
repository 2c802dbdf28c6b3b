"""Simulated twins of every device and the physical farm they act on.

A device marked ``driver = "sim"`` in farm.toml is served by ``fishfarm sim`` (its own
process, see controller/cli/sim_cmd.py) over the same protocol as the hardware: the contact
hub on a pseudo-terminal, the rail drive over slcan on a pseudo-terminal, the dispenser as a
Modbus TCP server. The controller then reaches it through the real driver.
"""
from __future__ import annotations

from devices.base import Section


class SimContactsSection(Section):
    """The simulated contact hub reports every sensor of every tank in the config."""


class SimRailSection(Section):
    node_id: int = 1


class SimDispenserSection(Section):
    host: str = "127.0.0.1"
    port: int = 0          # 0: any free port, reported by the sim process
    unit: int = 1


SIM_SECTIONS = {
    "contacts": SimContactsSection,
    "rail": SimRailSection,
    "dispenser": SimDispenserSection,
}
