"""The Modbus register map: ONE table (``TABLE``), laid out per farm by ``layout(cfg)``.

Each row is one value of a block: the farm, the feeder, the cleaner, the alarm summary, one alarm
slot (repeated per slot) or one tank (repeated per tank, in config order). A row's ``offset`` is
its address within its block; ``BLOCKS`` gives each block's base address and stride per table.
Everything else — config/modbus_map.csv, README's table, the server's reads and the guard on its
writes — is generated from these two.

    python -m controller.scada.register_map [--config config/farm.toml] > config/modbus_map.csv
    python -m controller.scada.register_map --markdown      # README's block table
"""
from __future__ import annotations

import csv
import io
import json
import math
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

from controller.scada.words import WORDS

COIL, DI, IR, HR = "coil", "discrete input", "input register", "holding register"
KINDS = (COIL, DI, IR, HR)
# "no value": what a register reads while the controller does not know the value (SunSpec's markers)
MAP_VERSION = 1
FEEDER_STATES = ("starting", "idle", "homing", "moving", "dispensing", "refilling", "fault", "estop", "manual",
                 "surveying")         # appended: a code once given keeps its meaning
SEVERITY = {None: 0, "info": 1, "warning": 2, "critical": 3}
MAX_SLOTS = 40
RATION_MAX_G = 1_000_000.0     # as controller/overrides.py: a tonne a day for one tank


@dataclass(frozen=True)
class Write:
    """What a write to the row means: the override command, and the values accepted (others: 03)."""
    command: str
    limits: Callable = lambda cfg: (None, None)     # (lowest, highest) accepted, from the config


@dataclass(frozen=True)
class Row:
    block: str
    name: str
    kind: str
    offset: int
    dtype: str
    scale: float
    units: str
    access: str             # R, R/W, or W (a momentary command: reads 0)
    description: str
    value: Callable = field(default=lambda v: None, repr=False)   # View -> python value or None
    write: Write | None = None


def _t(key):
    return lambda v: v.tank.get(key)


def _feeder_state(v):
    state = v.s["feeder"].get("state")
    return FEEDER_STATES.index(state) if state in FEEDER_STATES else None


def _bit(x):
    return None if x is None else int(bool(x))


_FEED = Write("feed", lambda cfg: (math.ceil(cfg.feeding.min_portion_g), math.floor(cfg.feeding.portion_g)))
_STATES = ", ".join(f"{i} {s}" for i, s in enumerate(FEEDER_STATES))

TABLE: tuple[Row, ...] = (
    # -- the farm: is the controller alive, and how is the map laid out -------------------------
    Row("farm", "heartbeat", IR, 0, "u16", 1, "", "R", "counts up at every snapshot refresh (wraps 65534 -> 0): "
        "a value that stops moving is a frozen controller", lambda v: v.heartbeat),
    Row("farm", "uptime_s", IR, 1, "u32", 1, "s", "R", "wall seconds since the controller started",
        lambda v: v.uptime_s),
    Row("farm", "map_version", IR, 3, "u16", 1, "", "R", f"layout version of this map ({MAP_VERSION})",
        lambda v: MAP_VERSION),
    Row("farm", "tank_count", IR, 4, "u16", 1, "", "R", "tanks in the map, config order", lambda v: len(v.tanks)),
    Row("farm", "word_order", IR, 5, "u16", 1, "", "R", "32-bit word order in use: 0 big (high word first), "
        "1 little (low word first)", lambda v: int(v.word_order == "little")),
    Row("farm", "farm_time", IR, 6, "u32", 1, "s", "R", "the farm clock of the snapshot, Unix seconds UTC",
        lambda v: v.s.get("t_unix")),
    Row("farm", "layout_crc", IR, 8, "u32", 1, "", "R", "CRC-32 of the tank ids in map order and the alarm "
        "slots: it changes when a config edit adds, removes or reorders tanks or devices (the blocks move); a "
        "SCADA checks it against the one its tags were made for", lambda v: v.layout_crc),
    Row("farm", "estop", COIL, 0, "bool", 1, "", "R/W", "e-stop latch: write 1 stops auger and drive at once "
        "(latched, as the Zenoh estop); writing 0 is refused (03): release with reset. Reads 1 while latched",
        lambda v: v.s["feeder"].get("state") == "estop", Write("estop")),
    Row("farm", "reset", COIL, 1, "bool", 1, "", "W", "write 1: operator reset (releases the e-stop latch, "
        "clears a fault); reads 0", write=Write("reset")),
    Row("farm", "ack_all", COIL, 2, "bool", 1, "", "W", "write 1: acknowledge every standing alarm; reads 0",
        write=Write("ack")),
    Row("farm", "estop_latched", DI, 0, "bool", 1, "", "R", "the feeder is in e-stop",
        lambda v: v.s["feeder"].get("state") == "estop"),
    Row("farm", "ready", DI, 1, "bool", 1, "", "R", "the controller is up (its devices opened)",
        lambda v: v.s["feeder"].get("state") not in (None, "starting") and not v.s["feeder"].get("starting")),
    Row("farm", "writes_enabled", DI, 2, "bool", 1, "", "R", "writes are accepted ([scada] read_only = false)",
        lambda v: not v.read_only),
    # -- the rail feeding robot ---------------------------------------------------------------
    Row("feeder", "feeder.state", IR, 0, "u16", 1, "", "R", f"feeder state: {_STATES}", _feeder_state),
    Row("feeder", "feeder.position_m", IR, 1, "f32", 1, "m", "R", "carriage position along the rail from home",
        lambda v: v.s["feeder"].get("position_m")),
    Row("feeder", "feeder.hopper_g", IR, 3, "f32", 1, "g", "R", "food in the hopper",
        lambda v: v.s["feeder"].get("hopper_g")),
    # -- the pond cleaner: "no value" on a farm without [cleaning] -------------------------------
    Row("cleaner", "cleaner.state", IR, 0, "u16", 1, "", "R", "cleaner state: 0 docked, 1 localising, 2 cleaning, "
        "3 returning, 4 lost, 5 fault, 6 estop, 7 manual (no value without [cleaning])",
        lambda v: (v.s.get("cleaner") or {}).get("state_code")),
    Row("cleaner", "cleaner.x_m", IR, 1, "f32", 1, "m", "R",
        "cleaner position x in the pond (no value while not tracked)",
        lambda v: (v.s.get("cleaner") or {}).get("x_m")),
    Row("cleaner", "cleaner.y_m", IR, 3, "f32", 1, "m", "R",
        "cleaner position y in the pond (no value while not tracked)",
        lambda v: (v.s.get("cleaner") or {}).get("y_m")),
    Row("cleaner", "cleaner.heading_rad", IR, 5, "f32", 1, "rad", "R", "cleaner heading (no value while not tracked)",
        lambda v: (v.s.get("cleaner") or {}).get("heading_rad")),
    Row("cleaner", "cleaner.coverage", IR, 7, "f32", 1, "", "R", "share of the reachable floor cleaned this run, 0..1",
        lambda v: (v.s.get("cleaner") or {}).get("coverage")),
    # -- alarms: the summary, then one slot per source known at start ---------------------------
    Row("alarms", "alarms.active", IR, 0, "u16", 1, "", "R", "standing alarms",
        lambda v: len(v.s["alarms"])),
    Row("alarms", "alarms.unacked", IR, 1, "u16", 1, "", "R", "standing alarms not acknowledged",
        lambda v: sum(not a.get("acked") for a in v.s["alarms"])),
    Row("alarms", "alarms.highest", IR, 2, "u16", 1, "", "R", "highest standing severity: 0 none, 1 info, "
        "2 warning, 3 critical", lambda v: max((SEVERITY.get(a["severity"], 3) for a in v.s["alarms"]), default=0)),
    Row("slot", "severity", IR, 0, "u16", 1, "", "R", "highest standing severity of the slot's alarms "
        "(0 none, 1 info, 2 warning, 3 critical)", lambda v: max((SEVERITY.get(a["severity"], 3) for a in v.slot),
                                                                 default=0)),
    Row("slot", "active", DI, 0, "bool", 1, "", "R", "an alarm of the slot stands", lambda v: bool(v.slot)),
    Row("slot", "unacked", DI, 1, "bool", 1, "", "R", "a standing alarm of the slot is not acknowledged",
        lambda v: any(not a.get("acked") for a in v.slot)),
    Row("slot", "ack", COIL, 0, "bool", 1, "", "W", "write 1: acknowledge the slot's standing alarms; reads 0",
        write=Write("ack")),
    # -- per tank, config order -------------------------------------------------------------------
    Row("tank", "demand", IR, 0, "u16", 1, "", "R", "1: a validated demand waits to be served", _t("demand")),
    Row("tank", "paused", IR, 1, "u16", 1, "", "R", "1: feeding paused by an operator",
        lambda v: _bit(v.tank.get("paused"))),
    Row("tank", "ration_g", IR, 2, "f32", 1, "g", "R", "today's ration", _t("ration_g")),
    Row("tank", "fed_g", IR, 4, "f32", 1, "g", "R", "fed today", _t("fed_g")),
    Row("tank", "pellet_mm", IR, 6, "f32", 1, "mm", "R", "pellet size of today's ration", _t("pellet_mm")),
    Row("tank", "mean_weight_g", IR, 8, "f32", 1, "g", "R", "mean fish weight the ration uses (survey, projected "
        "or config)", _t("mean_weight_g")),
    Row("tank", "biomass_kg", IR, 10, "f32", 1, "kg", "R", "stock count x mean weight", _t("biomass_kg")),
    Row("tank", "stock", IR, 12, "u32", 1, "fish", "R", "stock count", _t("stock")),
    Row("tank", "last_survey_t", IR, 14, "u32", 1, "s", "R", "last weight survey, Unix seconds UTC",
        _t("last_survey_unix")),
    Row("tank", "alarm_severity", IR, 16, "u16", 1, "", "R", "highest standing severity of the tank's sensor, "
        "demand, grading and survey alarms (0 none .. 3 critical)", _t("alarm_severity")),
    Row("tank", "weight_cv_pct", IR, 17, "u16", 0.1, "%", "R", "size uniformity: weight CV of the last survey",
        _t("weight_cv_pct")),
    Row("tank", "sgr_pct_day", IR, 18, "i16", 0.01, "%/day", "R", "specific growth rate between the last two "
        "surveys", _t("sgr_pct_day")),
    Row("tank", "fcr", IR, 19, "u16", 0.01, "", "R", "feed conversion ratio between the last two surveys "
        "(feed / biomass gain; the dead fish's growth counted: biological)", _t("fcr")),
    Row("tank", "feed_now_g", HR, 0, "u16", 1, "g", "W", "write grams: feed this tank now (feeding.min_portion_g "
        "to feeding.portion_g, else 03); reads 0", write=_FEED),
    Row("tank", "set_ration_g", HR, 1, "f32", 1, "g", "R/W", f"today's ration; write to set it (0 to {RATION_MAX_G:g}, "
        "both words in one request)", _t("ration_g"), Write("ration", lambda cfg: (0.0, RATION_MAX_G))),
    Row("tank", "pause", COIL, 0, "bool", 1, "", "R/W", "1 pause feeding this tank, 0 resume; reads 1 while paused",
        lambda v: bool(v.tank.get("paused")), Write("pause")),
    # -- per tank, config order: its survey coils, a block of their own (the tank's coils are 1 apart) --
    Row("survey", "start_survey", COIL, 0, "bool", 1, "", "W", "write 1: survey this tank's fish now (the rail "
        "robot's survey stop, once no demand waits; refused without a stereo camera or while paused); reads 0",
        write=Write("start-survey")),
    # -- per tank, config order: its water, a block of their own (the tank's 20 words were taken) ---
    Row("water", "water_temp_c", IR, 0, "i16", 0.01, "°C", "R", "the water temperature the tank's ration uses",
        _t("water_temp_c")),
    Row("water", "water_temp_source", IR, 1, "u16", 1, "", "R", "where that temperature comes from: 0 a probe's "
        "fresh reading, 1 the configured figure (no probe, or its reading is stale or at fault)",
        lambda v: {"sensor": 0, "config": 1}.get(v.tank.get("water_temp_source"))),
    # -- per tank, config order: its growth fitted to the surveys of the window (controller/growth.py) --
    Row("growth", "sgr_fit_pct_day", IR, 0, "i16", 0.01, "%/day", "R", "specific growth rate fitted to the "
        "surveys of the growth window", _t("sgr_fit_pct_day")),
    Row("growth", "sgr_fit_ci_pct_day", IR, 1, "u16", 0.01, "%/day", "R", "half-width of that SGR's 95 % interval",
        _t("sgr_fit_ci_pct_day")),
    Row("growth", "fcr_fit", IR, 2, "u16", 0.01, "", "R", "feed conversion ratio over the growth window "
        "(feed / biomass gain; biological)", _t("fcr_fit")),
    Row("growth", "fcr_fit_low", IR, 3, "u16", 0.01, "", "R", "low end of that FCR's 95 % interval",
        lambda v: (v.tank.get("fcr_fit_ci") or [None, None])[0]),
    Row("growth", "fcr_fit_high", IR, 4, "u16", 0.01, "", "R", "high end of that FCR's 95 % interval (no value: "
        "unbounded)", lambda v: (v.tank.get("fcr_fit_ci") or [None, None])[1]),
    Row("growth", "weight_ci_pct", IR, 5, "u16", 0.1, "%", "R", "half-width of the 95 % interval of the mean "
        "weight the ration uses", _t("weight_ci_pct")),
    Row("growth", "fit_surveys", IR, 6, "u16", 1, "", "R", "surveys in the growth fit", _t("fit_surveys")),
    Row("growth", "fcr_net_fit", IR, 7, "u16", 0.01, "", "R", "net feed conversion ratio over the growth window "
        "(feed / the biomass gain the farm kept: the dead fish's left out)", _t("fcr_net_fit")),
)

# (base address, stride) of each block in each table; a block's rows sit at base + index * stride + offset
BLOCKS: dict[str, dict[str, tuple[int, int]]] = {
    "farm": {IR: (0, 0), COIL: (0, 0), DI: (0, 0)},
    "feeder": {IR: (10, 0)},
    "cleaner": {IR: (20, 0)},
    "alarms": {IR: (30, 0)},
    "slot": {IR: (40, 1), DI: (10, 2), COIL: (10, 1)},
    "tank": {IR: (100, 20), HR: (100, 4), COIL: (100, 1)},
    "survey": {COIL: (1100, 1)},
    "water": {IR: (10000, 2)},       # far past the tank block: 495 tanks before they meet
    "growth": {IR: (11000, 8)},      # past the water block's 500 tanks
}
PER_TANK = ("tank", "survey", "water", "growth")
FIXED_SLOTS = ("estop", "feeder", "ledger", "dispenser_counters", "sim", "controller", "scada")
LATER_SLOTS = ("water", "survey")     # after the devices' (added later: the slots before kept their addresses)


def alarm_slots(cfg) -> list[str]:
    """The alarm sources known at start, each a slot: an alarm belongs to slot S when its source is S
    or starts with ``S/`` (``controller`` holds ``controller/robot.run`` and its kin; ``water`` the
    probes' faults; ``survey`` a failed survey's). A tank's sensor, demand, grading and survey
    alarms are in the tank's block (``alarm_severity``)."""
    slots = list(FIXED_SLOTS) + [f"device/{name}" for name in cfg.devices] + list(LATER_SLOTS)
    return slots[:MAX_SLOTS]


@dataclass(frozen=True)
class Entry:
    row: Row
    name: str
    address: int
    index: int | None       # the tank's or slot's position, None for the single blocks
    label: str | None       # tank id or slot source

    @property
    def kind(self) -> str:
        return self.row.kind

    @property
    def words(self) -> int:
        return WORDS[self.row.dtype]


@dataclass
class Layout:
    entries: list[Entry]
    tanks: list[str]
    slots: list[str]
    extent: dict[str, int]        # per table: addresses 0 .. extent-1 may be read
    cfg: object = None

    @property
    def crc(self) -> int:
        """CRC-32 of the tank ids and alarm slots, in map order (``layout_crc``)."""
        return zlib.crc32(json.dumps([self.tanks, self.slots]).encode())

    def by_kind(self, kind: str) -> list[Entry]:
        return [e for e in self.entries if e.kind == kind]

    def at(self, kind: str) -> dict[int, Entry]:
        return {e.address: e for e in self.entries if e.kind == kind}


def layout(cfg) -> Layout:
    tanks = [t.id for t in cfg.tanks]
    slots = alarm_slots(cfg)
    entries: list[Entry] = []
    for row in TABLE:
        base, stride = BLOCKS[row.block][row.kind]
        if row.block in PER_TANK:
            labels = tanks
        elif row.block == "slot":
            labels = slots
        else:
            labels = [None]
        for i, label in enumerate(labels):
            if row.block in PER_TANK:
                name = f"tank.{label}.{row.name}"
            elif row.block == "slot":
                name = f"alarm.{label}.{row.name}"
            else:
                name = row.name
            entries.append(Entry(row, name, base + i * stride + row.offset, None if label is None else i, label))
    entries.sort(key=lambda e: (KINDS.index(e.kind), e.address))
    extent = {}
    for kind in KINDS:
        ends = [e.address + e.words for e in entries if e.kind == kind]
        if kind in BLOCKS["tank"] and tanks:       # a tank block reads whole, reserved words too
            base, stride = BLOCKS["tank"][kind]
            ends.append(base + stride * len(tanks))
        extent[kind] = max(ends, default=0)
    _check(entries)
    return Layout(entries, tanks, slots, extent, cfg)


def _check(entries: list[Entry]) -> None:
    """No two values share a word: a table edit that overlaps blocks fails at once, not on a farm."""
    seen: dict[tuple[str, int], str] = {}
    for e in entries:
        for w in range(e.words):
            key = (e.kind, e.address + w)
            if key in seen:
                raise ValueError(f"register map: {e.name} overlaps {seen[key]} at {e.kind} {e.address + w}")
            seen[key] = e.name
        if e.address + e.words > 0x10000:
            raise ValueError(f"register map: {e.name} beyond address 65535 (too many tanks?)")


# -- the written forms ------------------------------------------------------------------------------
COLUMNS = ("name", "type", "address", "data_type", "scale", "units", "access", "description")


def csv_text(lay: Layout) -> str:
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(COLUMNS)
    for e in lay.entries:
        r = e.row
        w.writerow([e.name, r.kind, e.address, r.dtype, f"{r.scale:g}", r.units, r.access, r.description])
    return out.getvalue()


def markdown() -> str:
    """README's table: every row once, with its block's base and stride."""
    lines = ["| block | name | type | address | data type | scale | units | access | description |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in TABLE:
        base, stride = BLOCKS[r.block][r.kind]
        where = f"{base + r.offset}" if not stride else f"{base} + {stride}·i + {r.offset}"
        lines.append(f"| {r.block} | {r.name} | {r.kind} | {where} | {r.dtype} | {r.scale:g} | {r.units} | "
                     f"{r.access} | {r.description.replace('|', '/')} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    import argparse

    from controller.config import load_config
    from controller.errors import BadInput

    p = argparse.ArgumentParser(prog="python -m controller.scada.register_map",
                                description="Write the Modbus register map as CSV (or README's markdown).")
    p.add_argument("--config", default="config/farm.toml")
    p.add_argument("--markdown", action="store_true", help="README's block table instead of the CSV")
    args = p.parse_args(argv)
    if args.markdown:
        sys.stdout.write(markdown())
        return 0
    try:
        cfg = load_config(args.config)
    except BadInput as exc:
        print(f"fishfarm: {exc}", file=sys.stderr)
        return 2
    sys.stdout.write(csv_text(layout(cfg)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
