"""The water thermometer's coordinator: the temperatures the rations are read at.

It polls the transmitter every ``[feeding] water_poll_s`` farm seconds and keeps each probe's last
good reading. A tank reads its own probe (named by the tank's id), else the farm's ``supply``
probe; a reading older than ``water_max_age_s`` is not used, and the tank falls back to its
configured temperature (the tank's ``water_temp_c``, else ``[feeding]``'s) — ``temperature()``
says which. Consumers never touch the device. A faulty probe (open, shorted, out of range) is one
alarm until it reads again; a transmitter that does not answer is one alarm until it does
(Home Assistant's rule: logged once on loss, once on recovery).
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
from dataclasses import dataclass

from devices.errors import DeviceError

log = logging.getLogger("fishfarm.water")

SUPPLY = "supply"
RETRY_S = (1.0, 2.0, 5.0, 10.0, 30.0)   # wall seconds between attempts to reopen a lost transmitter


@dataclass(frozen=True)
class WaterTemp:
    celsius: float
    source: str             # "sensor" (a fresh reading of ``probe``) or "config"
    probe: str | None = None
    t: float | None = None  # when it was read


class WaterTemperatures:
    """``device``: a devices.thermometer.Thermometer, or None (the config's temperatures only)."""

    def __init__(self, cfg, device, clock, alarms=None, *, reopen=None, on_fresh=None):
        self.cfg, self.device, self.clock, self.alarms = cfg, device, clock, alarms
        self.reopen = reopen
        self.on_fresh = on_fresh              # on_fresh(tank_ids): their water is measured again
        self.latest: dict[str, tuple[float, float]] = {}    # probe -> (celsius, t) of its last good reading
        self.faults: dict[str, str] = {}

    def probe_of(self, tank_id: str) -> str | None:
        if self.device is None:
            return None
        probes = self.device.probes
        return tank_id if tank_id in probes else SUPPLY if SUPPLY in probes else None

    def temperature(self, tank_id: str, t: float | None = None) -> WaterTemp:
        """The tank's water at ``t`` (now): its probe's fresh reading, else the configured value."""
        t = self.clock.now() if t is None else t
        probe = self.probe_of(tank_id)
        seen = self.latest.get(probe) if probe is not None else None
        if seen is not None and 0 <= t - seen[1] <= self.cfg.feeding.water_max_age_s:
            return WaterTemp(seen[0], "sensor", probe, seen[1])
        tank = self.cfg.tank(tank_id)
        configured = tank.water_temp_c if tank.water_temp_c is not None else self.cfg.feeding.water_temp_c
        return WaterTemp(configured, "config", probe)

    def record(self, readings: dict, t: float) -> list[str]:
        """One poll's readings (probe -> devices.thermometer.ProbeReading); returns the tanks whose
        water is measured again (their temperature was the config's until now)."""
        before = {tank.id: self.temperature(tank.id, t).source for tank in self.cfg.tanks}
        for name, r in readings.items():
            if r.fault is None and r.celsius is not None:
                self.latest[name] = (r.celsius, t)
                if self.faults.pop(name, None) is not None and self.alarms is not None:
                    self.alarms.clear(self._source(name), f"probe {name} reads again: {r.celsius:.1f} °C")
            elif self.faults.get(name) != r.fault:
                self.faults[name] = r.fault
                if self.alarms is not None:
                    # the last good reading serves while fresh: the alarm must not say otherwise
                    self.alarms.raise_(self._source(name), f"water probe {name}: {r.fault}; the rations use "
                                       f"its last good reading for up to {self.cfg.feeding.water_max_age_s:g} s, "
                                       "then the configured temperature", kind="probe")
        return [tank for tank, was in before.items()
                if was == "config" and self.temperature(tank, t).source == "sensor"]

    def snapshot(self) -> dict:
        return {name: {"celsius": c, "t": self.clock.iso(t), "fault": self.faults.get(name)}
                for name, (c, t) in sorted(self.latest.items())} | {
                name: {"celsius": None, "t": None, "fault": f}
                for name, f in sorted(self.faults.items()) if name not in self.latest}

    def _source(self, probe: str) -> str:
        return f"water/{probe}"

    async def poll_once(self) -> bool:
        """Read the transmitter once; False when it did not answer (alarmed once)."""
        try:
            readings = await self.device.read()
        except DeviceError as exc:
            if self.alarms is not None:
                self.alarms.raise_(f"device/{self.device.name}", exc.text, kind="unreachable")
            return False
        if self.alarms is not None:
            self.alarms.clear(f"device/{self.device.name}", "thermometer answers")
        fresh = self.record(readings, self.clock.now())
        if fresh and self.on_fresh is not None:
            self.on_fresh(fresh)
        return True

    async def run(self, stopping: asyncio.Event) -> None:
        """Poll until ``stopping``; a lost transmitter is reopened (``reopen(device)`` -> fresh)."""
        failures = 0
        while not stopping.is_set():
            if await self.poll_once():
                failures = 0
                await self.clock.asleep(self.cfg.feeding.water_poll_s)
                continue
            failures += 1
            await _pause(stopping, RETRY_S[min(failures - 1, len(RETRY_S) - 1)])
            if self.reopen is not None and not stopping.is_set():
                with contextlib.suppress(DeviceError):
                    self.device = await self.reopen(self.device)


async def _pause(stopping: asyncio.Event, seconds: float) -> None:
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(stopping.wait(), seconds)


def check_thermometer(cfg) -> None:
    """At most one thermometer, and each probe named by a tank's id or ``supply``."""
    from controller.errors import BadInput
    found = [(name, s) for name, s in cfg.devices.items() if s["kind"] == "thermometer"]
    if len(found) > 1:
        raise BadInput(cfg.path, f"devices.{found[1][0]}", "a second thermometer (one transmitter "
                                                            "reads every probe)")
    tanks = {t.id for t in cfg.tanks}
    for name, section in found:
        for probe in section.get("probes") or {}:
            if probe not in tanks and probe != SUPPLY:
                raise BadInput(cfg.path, f"devices.{name}.probes.{probe}",
                               f"not a tank id nor {SUPPLY!r} (tanks: {', '.join(sorted(tanks))})")
    # the simulated water's per-probe settings name probes the transmitter reads: a name that is none
    # (offsets_c = {T55 = 1.5}) was taken and never used
    probes = {p for _, section in found for p in section.get("probes") or {}}
    water = cfg.sim.get("thermometer") if isinstance(cfg.sim, dict) and found else None   # none: unused
    for field in ("offsets_c", "faults"):
        given = water.get(field) if isinstance(water, dict) else None
        for probe in given if isinstance(given, dict) else {}:
            if probe not in probes:
                raise BadInput(cfg.path, f"sim.thermometer.{field}.{probe}",
                               f"not a probe of the thermometer (probes: {', '.join(sorted(probes))})")
