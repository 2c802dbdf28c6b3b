"""Simulated twins of every device and the physical farm they act on.

A device marked ``driver = "sim"`` in farm.toml is served by ``fishfarm sim`` (its own
process, see controller/cli/sim_cmd.py) over the same protocol as the hardware: the contact
hub on a pseudo-terminal, the rail drive over slcan on a pseudo-terminal, the dispenser as a
Modbus TCP server, the cleaner's thruster controller on a pseudo-terminal, the tower camera
as an MJPEG-over-HTTP server, the survey cameras the same way (both views side by side),
the water thermometer as a Modbus TCP server. The controller then reaches it through the
real driver.
"""
from __future__ import annotations

from pydantic import Field, field_validator

from devices.base import Section
from devices.thermometer.modbus_thermometer import check_probes


class SimContactsSection(Section):
    """The simulated contact hub reports every sensor of every tank in the config."""


class SimRailSection(Section):
    node_id: int = Field(1, ge=1, le=127)


class SimDispenserSection(Section):
    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(0, ge=0, le=65535, description="0: any free port, reported by the sim process")
    unit: int = Field(1, ge=0, le=247)


class SimThrustersSection(Section):
    """The simulated thruster controller (``[sim.thrusters]``: its watchdog, ramps)."""

    watchdog_s: float | None = Field(None, ge=0.05, le=600, description="set by the controller on open")


class SimTowerCameraSection(Section):
    """The simulated tower camera (``[sim.tower_camera]``: size, frame rate) over the pond (``[sim.pond]``)."""

    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(0, ge=0, le=65535, description="0: any free port, reported by the sim process")


class SimThermometerSection(Section):
    """The simulated water temperature transmitter over the water model (``[sim.thermometer]``)."""

    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(0, ge=0, le=65535, description="0: any free port, reported by the sim process")
    unit: int = Field(1, ge=0, le=247)
    probes: dict[str, int] = Field(description="probe name -> channel, as the real transmitter's")

    @field_validator("probes")
    @classmethod
    def _channels(cls, probes: dict[str, int]) -> dict[str, int]:
        return check_probes(probes)


class SimStereoCameraSection(Section):
    """The simulated survey cameras on the carriage (``[sim.stereo_camera]``: size, rate, fish)."""

    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(0, ge=0, le=65535, description="0: any free port, reported by the sim process")


SIM_SECTIONS = {
    "contacts": SimContactsSection,
    "rail": SimRailSection,
    "dispenser": SimDispenserSection,
    "thrusters": SimThrustersSection,
    "tower_camera": SimTowerCameraSection,
    "thermometer": SimThermometerSection,
    "stereo_camera": SimStereoCameraSection,
}
