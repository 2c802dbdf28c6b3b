"""The simulated water temperature transmitter: a model of the tanks' water behind the Modbus TCP
register map of devices/thermometer/modbus_thermometer.py, served by pymodbus (a read refreshes
the channels from the model at that instant, pymodbus's own ``SimDevice.action`` way).

The water (``WaterModel``): a yearly cycle (``mean_c`` ± ``seasonal_amp_c``, warmest on
``warmest_day`` of the year), a daily one (± ``diurnal_amp_c``, warmest at ``warmest_hour``
local time), a steady offset per probe (a tank in the shade, a recirculating tank with a heater),
and a probe's own noise. Faults: a probe listed in ``faults`` reads open or shorted; a probe can
also fail or heal while running (``set_fault``).
"""
from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from devices.sections import validate_section
from devices.thermometer.modbus_thermometer import MAX_CHANNELS, encode

DAY_S = 86400.0
YEAR_D = 365.25


class WaterParams(BaseModel):
    """farm.toml ``[sim.thermometer]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    mean_c: float = Field(20.0, ge=-2, le=35, description="the year's mean water temperature")
    seasonal_amp_c: float = Field(4.0, ge=0, le=15)
    warmest_day: float = Field(225.0, ge=0, le=366, description="day of the year of the warmest water")
    diurnal_amp_c: float = Field(0.5, ge=0, le=5)
    warmest_hour: float = Field(16.0, ge=0, lt=24, description="local hour of the day's warmest water")
    utc_offset_h: float = Field(0.0, ge=-12, le=14)
    offsets_c: dict[str, float] = Field({}, description="probe -> steady offset")
    noise_c: float = Field(0.05, ge=0, le=2, description="a probe's own noise, sd")
    faults: dict[str, str] = Field({}, description="probe -> 'open' or 'short' from the start")
    seed: int = 0


class WaterModel:
    """Temperatures by probe at farm time ``t`` (epoch seconds)."""

    def __init__(self, params: WaterParams):
        self.params = params
        self.rng = np.random.default_rng(params.seed)

    def true_c(self, probe: str, t: float) -> float:
        """The water itself, without the probe's noise (the HIL's ground truth)."""
        p = self.params
        local = t + p.utc_offset_h * 3600.0
        day_of_year = (local / DAY_S) % YEAR_D
        hour = (local % DAY_S) / 3600.0
        season = p.seasonal_amp_c * math.cos(2 * math.pi * (day_of_year - p.warmest_day) / YEAR_D)
        day = p.diurnal_amp_c * math.cos(2 * math.pi * (hour - p.warmest_hour) / 24.0)
        return p.mean_c + season + day + p.offsets_c.get(probe, 0.0)

    def read_c(self, probe: str, t: float) -> float:
        noise = self.rng.normal(0.0, self.params.noise_c) if self.params.noise_c else 0.0
        return self.true_c(probe, t) + noise


class SimThermometer:
    """The transmitter on Modbus TCP: ``probes`` name -> channel, as in the driver's config."""

    def __init__(self, params: WaterParams | dict, clock, probes: dict[str, int], *, host: str = "127.0.0.1",
                 port: int = 0, unit: int = 1, register: int = 1, where: str = "farm.toml"):
        if not isinstance(params, WaterParams):
            params = validate_section(WaterParams, params, where, "sim.thermometer")
        self.water = WaterModel(params)
        self.clock = clock
        self.probes = dict(probes)
        self.faults = dict(params.faults)
        self.host, self.port, self.unit, self.register = host, port, unit, register
        self.reads = 0
        self._server: ModbusTcpServer | None = None

    def set_fault(self, probe: str, fault: str | None) -> None:
        """A probe's wire breaks ("open"), shorts ("short"), or is mended (None)."""
        if fault is None:
            self.faults.pop(probe, None)
        else:
            self.faults[probe] = fault

    def registers(self, t: float) -> list[int]:
        """Every channel's register at ``t`` (unused channels read 0)."""
        words = [0] * MAX_CHANNELS
        for probe, channel in self.probes.items():
            fault = self.faults.get(probe)
            words[channel] = encode(None if fault else self.water.read_c(probe, t), fault)
        return words

    async def start(self) -> None:
        device = SimDevice(self.unit, action=self._action, simdata=[
            SimData(self.register, count=MAX_CHANNELS, datatype=DataType.REGISTERS, readonly=True)])
        self._server = ModbusTcpServer(device, address=(self.host, self.port))
        try:
            await self._server.serve_forever(background=True)
        except RuntimeError:
            self._server = None
            raise OSError(f"simulated thermometer cannot listen on {self.host}:{self.port}") from None
        self.port = self._server.transport.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        if self._server is not None:
            server, self._server = self._server, None
            await server.shutdown()

    async def _action(self, fc, start, address, count, registers, values):
        self.reads += 1
        at = self.register - start
        registers[at:at + MAX_CHANNELS] = self.registers(self.clock.now())
        return None
