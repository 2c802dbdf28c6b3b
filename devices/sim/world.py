"""The simulated farm: tanks of fish, the rail carriage and the dispenser on it, in one process.

Each simulated device serves its own protocol; the world only links their physics: food
leaving the auger falls into the tank under the carriage (or on the floor between tanks),
and the hopper refills only while the carriage stands at the food box.
"""
from __future__ import annotations

import logging
import random
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from controller.config import Config, validate_section
from controller.errors import BadInput
from devices.sim.dispenser import SimDispenser, SimDispenserParams
from devices.sim.rail import SimRailMotor, SimRailParams
from devices.sim.slcan_adapter import SlcanAdapter
from devices.sim.truth import TruthLog

log = logging.getLogger("fishfarm.sim")

TANK_MOUTH_M = 0.30       # the chute is over a tank when within this of the tank's position
FOOD_BOX_M = 0.10         # the hopper fills only this close to the food box


class SimSection(BaseModel):
    """farm.toml ``[sim]``: the simulated world. Each part validates its own sub-section."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    seed: int = 0
    fish: dict[str, Any] = {}
    contacts: dict[str, Any] = {}
    rail: dict[str, Any] = {}
    dispenser: dict[str, Any] = {}
    soak_days: float = Field(0.0, ge=0, description="reserved")


class SimFarm:
    def __init__(self, cfg: Config, clock, truth: TruthLog | None = None):
        self.cfg, self.clock = cfg, clock
        self.truth = truth or TruthLog(None)
        self.section = validate_section(SimSection, cfg.sim, cfg.path, "sim")
        self.rng = random.Random(self.section.seed)
        simulated = [(n, s) for n, s in cfg.devices.items() if s["driver"] == "sim"]
        self.devices = {kind: [(n, s) for n, s in simulated if s["kind"] == kind]
                        for kind in ("contacts", "rail", "dispenser")}
        self.motor: SimRailMotor | None = None
        self.adapter: SlcanAdapter | None = None
        self.dispenser: SimDispenser | None = None
        self.tanks = self._build_tanks()
        self.hubs: list = []
        self.tank_positions = sorted((t.position_m, t.id) for t in cfg.tanks)
        self.spilled_g = 0.0

    # -- physics links -----------------------------------------------------------
    def carriage_m(self, t: float) -> float:
        return self.motor.position(t) if self.motor is not None else self.cfg.feeding.food_box_m

    def tank_under(self, position_m: float) -> str | None:
        for tank_pos, tank_id in self.tank_positions:
            if abs(tank_pos - position_m) <= TANK_MOUTH_M:
                return tank_id
        return None

    def deliver(self, grams: float, t: float) -> None:
        """Food leaving the auger at farm time ``t`` (called under the dispenser's lock: no blocking)."""
        tank = self.tank_under(self.carriage_m(t))
        if tank is None:
            self.spilled_g += grams
        elif tank in self.tanks:
            self.tanks[tank].feed(grams, t)
        self.truth.write("delivered", t, tank=tank, grams=round(grams, 4))

    def at_food_box(self, t: float) -> bool:
        return abs(self.carriage_m(t) - self.cfg.feeding.food_box_m) <= FOOD_BOX_M

    # -- life cycle ----------------------------------------------------------------
    def _build_tanks(self) -> dict:
        if not self.devices["contacts"]:
            return {}
        from devices.sim.fish import SimFishParams, SimTank
        params = validate_section(SimFishParams, self.section.fish, self.cfg.path, "sim.fish")
        import numpy as np
        seeds = np.random.SeedSequence(self.section.seed).spawn(len(self.cfg.tanks))
        return {t.id: SimTank(t, params, np.random.default_rng(s), self.truth)
                for t, s in zip(self.cfg.tanks, seeds, strict=True)}

    async def start(self) -> dict[str, dict]:
        """Start every simulated device; return the real-driver config section for each."""
        endpoints: dict[str, dict] = {}
        where = self.cfg.path
        for name, section in self.devices["rail"][:1]:
            params = validate_section(SimRailParams, self.section.rail, where, "sim.rail")
            self.motor = SimRailMotor(params, self.clock, node_id=section.get("node_id", 1))
            self.adapter = SlcanAdapter()
            await self.motor.start(self.adapter)
            endpoints[name] = {"kind": "rail", "driver": "can", "interface": "slcan",
                               "channel": self.adapter.port, "node_id": section.get("node_id", 1)}
        for name, section in self.devices["dispenser"][:1]:
            params = validate_section(SimDispenserParams, self.section.dispenser, where, "sim.dispenser")
            host, unit = section.get("host", "127.0.0.1"), section.get("unit", 1)
            self.dispenser = SimDispenser(params, self.clock, host=host, port=section.get("port", 0), unit=unit,
                                          deliver=self.deliver, at_food_box=self.at_food_box, truth=self.truth)
            try:
                await self.dispenser.start()
            except OSError as exc:
                raise BadInput(where, f"devices.{name}.port", str(exc)) from None
            endpoints[name] = {"kind": "dispenser", "driver": "modbus", "host": host,
                               "port": self.dispenser.port, "unit": unit}
        for name, _section in self.devices["contacts"]:
            endpoints[name] = await self._start_hub()
        return endpoints

    async def _start_hub(self) -> dict:
        from devices.sim.contact_hub import SimContactHub
        hub = SimContactHub(list(self.tanks.values()), self.clock, self.section.contacts, self.truth)
        await hub.start()
        self.hubs.append(hub)
        return {"kind": "contacts", "driver": "serial", "port": hub.port}

    async def stop(self) -> None:
        for hub in self.hubs:
            await hub.stop()
            self.truth.write("contact_hub", self.clock.now(), sent=hub.sent, dropped=hub.dropped)
        if self.dispenser is not None:
            self.truth.write("dispenser_total", self.clock.now(), physical_g=self.dispenser.physical_total_g)
            await self.dispenser.stop()
        if self.motor is not None:
            await self.motor.stop()
        self.truth.close()
