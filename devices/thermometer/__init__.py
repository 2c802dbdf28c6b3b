"""Water temperature: a transmitter with one probe per tank (or one on the farm's water supply).

Interface: ``Thermometer``. Backends, chosen by ``driver`` through ``BACKENDS``:
- ``modbus``: a multi-channel temperature transmitter (PT100/NTC module) over Modbus TCP, one input
  register per channel. Register map in modbus_thermometer.py and README.md.
- ``sim``:    the simulated twin (devices/sim/thermometer.py), a pymodbus server over a model of the
  water (season, day, tank offsets, noise), reached by ``modbus``.

``read()`` answers every probe in one request, so the readings are one snapshot. A probe that is
open or shorted is a reading with ``fault`` set and no temperature, not an error: the other probes
still count. A transmitter that does not answer is DeviceTimeout / LinkDown, as for every kind.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass

from devices.base import Device


@dataclass(frozen=True, slots=True)
class ProbeReading:
    probe: str
    celsius: float | None      # None when the probe is faulty
    fault: str | None = None   # "open" (wire broken), "short", "range" (outside the module's span)


class Thermometer(Device):
    kind = "thermometer"

    @property
    def probes(self) -> tuple[str, ...]:
        """The probe names this transmitter reads (its config's ``probes``)."""
        return tuple(self.config.probes)

    async def read(self) -> dict[str, ProbeReading]:
        """Every probe, by name, in one exchange."""
        return await self._read()

    @abc.abstractmethod
    async def _read(self) -> dict[str, ProbeReading]: ...


BACKENDS = {
    "modbus": "devices.thermometer.modbus_thermometer:ModbusThermometer",
}
