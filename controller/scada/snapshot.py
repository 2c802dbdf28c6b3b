"""The snapshot the Modbus server answers from: ``Controller.status()`` turned into the words of
each table, refreshed by a coordinator every ``[scada] refresh_s`` wall seconds (Home Assistant's
rule: one coordinator publishes a typed snapshot; readers never reach a device).

A value the status does not hold (None, or a key absent) becomes the map's "no value" marker.
"""
from __future__ import annotations

import asyncio
import datetime as dt
import logging
import time
from dataclasses import dataclass, field

from controller.scada.register_map import COIL, DI, HR, IR, KINDS, PER_TANK, SEVERITY, Layout
from controller.scada.words import encode

log = logging.getLogger("fishfarm.scada")


def unix(iso: str | None) -> float | None:
    if not iso:
        return None
    try:
        return dt.datetime.fromisoformat(iso.replace("Z", "+00:00")).timestamp()
    except (TypeError, ValueError):
        return None


@dataclass
class View:
    """What a row's getter sees: the whole status, and the tank or alarm slot of its block."""
    s: dict
    heartbeat: int
    uptime_s: float
    word_order: str
    read_only: bool
    tanks: list
    tank: dict = field(default_factory=dict)
    slot: list = field(default_factory=list)
    layout_crc: int = 0


def in_slot(source: str, slot: str) -> bool:
    return source == slot or source.startswith(slot + "/")


def prepare(status: dict, lay: Layout) -> dict:
    """The status with what the map reads besides: Unix times, biomass, each tank's alarm severity;
    its alarms the standing ones only."""
    s = dict(status)
    s.setdefault("feeder", {})
    # the map speaks of standing alarms; status also lists the cleared ones not yet acknowledged
    s["alarms"] = [a for a in s.get("alarms") or [] if a.get("active", True)]
    s["t_unix"] = unix(s.get("t"))
    sensors = {}
    if lay.cfg is not None:
        sensors = {t.id: {f"sensor/{x}" for x in t.sensors} | {f"demand/{t.id}", f"grading/{t.id}", f"survey/{t.id}"}
                   for t in lay.cfg.tanks}
    tanks = {}
    for tank_id in lay.tanks:
        t = dict((s.get("tanks") or {}).get(tank_id) or {})
        stock, weight = t.get("stock"), t.get("mean_weight_g")
        if t.get("biomass_kg") is None and stock is not None and weight is not None:
            t["biomass_kg"] = stock * weight / 1000.0
        t["last_survey_unix"] = unix(t.get("last_survey_t"))
        mine = sensors.get(tank_id, ())
        t["alarm_severity"] = max((SEVERITY.get(a.get("severity"), 3) for a in s["alarms"]
                                   if a.get("source") in mine), default=0)
        tanks[tank_id] = t
    s["tanks"] = tanks
    return s


def render(status: dict, lay: Layout, *, heartbeat: int, uptime_s: float, word_order: str = "big",
           read_only: bool = False) -> dict[str, list[int]]:
    """Every table's words (bits as 0/1), index = protocol address; reserved words read "no value"."""
    s = prepare(status, lay)
    image = {kind: [0xFFFF if kind in (IR, HR) else 0] * lay.extent[kind] for kind in KINDS}
    view = View(s, heartbeat, uptime_s, word_order, read_only, lay.tanks, layout_crc=lay.crc)
    slots = {slot: [a for a in s["alarms"] if in_slot(a.get("source", ""), slot)] for slot in lay.slots}
    for e in lay.entries:
        r = e.row
        if r.block in PER_TANK:
            view.tank = s["tanks"][e.label]
        elif r.block == "slot":
            view.slot = slots[e.label]
        try:
            value = r.value(view)
        except (KeyError, TypeError, ValueError, AttributeError):     # a status without that part yet
            value = None
        if r.access == "W":
            value = 0           # a momentary command reads 0
        words = encode(r.dtype, value, r.scale, word_order)
        image[e.kind][e.address:e.address + len(words)] = words
    return image


class Coordinator:
    """Refreshes the snapshot from ``status()`` (cheap: no device is asked). Counts a heartbeat."""

    def __init__(self, status, lay: Layout, cfg, *, started: float | None = None, monotonic=time.monotonic):
        self.status, self.lay, self.cfg = status, lay, cfg
        self.monotonic = monotonic
        self.started = monotonic() if started is None else started
        self.heartbeat = 0
        self.image: dict[str, list[int]] = {}
        self.last_status: dict | None = None
        self.failed = False
        self.refresh()

    def refresh(self) -> None:
        try:
            status = self.status()
        except Exception:        # never the end of the server: the heartbeat stops, SCADA sees it
            if not self.failed:
                log.exception("scada: status() failed; every value reads \"no value\", the heartbeat holds")
            self.failed = True
            # what the controller cannot say now reads "no value", never the last number it said
            self.image = render({}, self.lay, heartbeat=self.heartbeat, uptime_s=self.monotonic() - self.started,
                                word_order=self.cfg.word_order, read_only=self.cfg.read_only)
            return
        if self.failed:
            log.info("scada: status() answers again")
            self.failed = False
        self.heartbeat = (self.heartbeat + 1) % 0xFFFF
        self.last_status = status
        uptime_s = status.get("uptime_s", self.monotonic() - self.started)
        self.image = render(status, self.lay, heartbeat=self.heartbeat, uptime_s=uptime_s,
                            word_order=self.cfg.word_order, read_only=self.cfg.read_only)


__all__ = ["COIL", "DI", "HR", "IR", "Coordinator", "View", "in_slot", "prepare", "refreshing", "render", "unix"]


async def refreshing(coordinator: Coordinator, every_s: float) -> None:
    """The coordinator's loop (supervised by the controller like its other loops)."""
    while True:
        await asyncio.sleep(every_s)
        coordinator.refresh()
