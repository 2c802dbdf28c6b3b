"""Contact sensors: the fish bump them when they want food.

Interface: ``ContactSensors`` (one hub reporting many sensors). Backends, chosen by the
config's ``driver`` through ``BACKENDS``:
- ``serial``: the real hub on a serial line (pyserial); line protocol in README.md.
- ``sim``:    the simulated twin (devices/sim), served on a pseudo-terminal and read by
              the ``serial`` backend, so the controller cannot tell the two apart.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass

from devices.base import Device


@dataclass(frozen=True, slots=True)
class Contact:
    """One rising edge. ``t`` is farm time (Unix s) as stamped by the hub, not arrival time."""

    t: float
    sensor: str


class ContactSensors(Device):
    kind = "contacts"

    async def read(self) -> list[Contact]:
        """Wait for contacts and return every one received so far (at least one), oldest first;
        the first line heard after the device opened returns even without contacts (an empty
        list: the line is alive, a heartbeat is enough).

        Raises LinkDown when the line is lost; malformed lines are counted in
        ``self.malformed`` and skipped, never raised."""
        if not self._opened or self._closed:
            raise RuntimeError(f"{self.name}: read() on a device that is not open")
        return await self._read()

    malformed: int = 0
    stream_t: float | None = None
    """Farm time up to which the hub has reported everything: its latest stamp (contact or
    heartbeat; a hub sends in time order) once read() has handed out every contact up to it.
    Time-driven judgements (a dead sensor, a drained demand) use this, not the local clock, so a
    line's latency never reorders the evidence."""

    @abc.abstractmethod
    async def _read(self) -> list[Contact]: ...


BACKENDS = {
    "serial": "devices.contacts.serial_hub:SerialContactHub",
}
