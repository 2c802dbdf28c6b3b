"""The dispenser on the feeding robot: hopper on a load cell, an auger, a refill gate.

Interface: ``Dispenser``. Backends, chosen by ``driver`` through ``BACKENDS``:
- ``modbus``: the real dispenser PLC over Modbus TCP (pymodbus). Register map in README.md.
- ``sim``:    the simulated twin, a pymodbus server (devices/sim) reached by ``modbus``.

Exactly-once dispensing rests on the device's own counters: every auger run carries a
``tag`` chosen by the controller; the device counts completed runs and keeps the tag and
load-cell grams of the last one, so after a restart the controller can tell whether an
intent it wrote ran, is running, or never started.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass

from devices.base import Device


@dataclass(frozen=True, slots=True)
class DispenserState:
    hopper_g: float         # load cell, resolution ``resolution_g``
    running: bool           # auger turning
    jammed: bool            # device tripped on motor current / no flow
    refilling: bool         # refill gate open
    cycles: int             # completed auger runs since power-on (wraps at 2**32)
    last_tag: int           # tag of the last completed (or jammed) run
    last_grams: float       # load-cell grams delivered by that run
    total_grams: float      # load-cell grams delivered since power-on
    resolution_g: float


class Dispenser(Device):
    kind = "dispenser"

    async def read(self) -> DispenserState:
        return await self._read()

    async def run_auger(self, run_s: float, tag: int) -> None:
        """Start one auger run of ``run_s`` farm seconds, timed by the device itself."""
        if not 0 < run_s <= 600:
            raise ValueError(f"{self.name}: auger run of {run_s} s is out of range")
        if not 0 < tag < 65536:
            raise ValueError(f"{self.name}: tag {tag} is out of range 1..65535")
        await self._run_auger(run_s, tag)

    async def stop(self) -> None: await self._stop()
    async def set_refill(self, open_gate: bool) -> None: await self._set_refill(open_gate)
    async def clear_fault(self) -> None: await self._clear_fault()

    @abc.abstractmethod
    async def _read(self) -> DispenserState: ...
    @abc.abstractmethod
    async def _run_auger(self, run_s: float, tag: int) -> None: ...
    @abc.abstractmethod
    async def _stop(self) -> None: ...
    @abc.abstractmethod
    async def _set_refill(self, open_gate: bool) -> None: ...
    @abc.abstractmethod
    async def _clear_fault(self) -> None: ...


BACKENDS = {
    "modbus": "devices.dispenser.modbus_dispenser:ModbusDispenser",
}
