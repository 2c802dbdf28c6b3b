"""farm.toml: load, validate, and say exactly what is wrong.

Each component owns the model of its own section (Klipper's rule); this module assembles
them and turns the first validation failure into one line: ``FILE: key.path: reason``.
Device sections are validated by the model their kind and driver name in ``devices``
(``devices.sections``, where ``validate_section`` lives too: devices/ must not import controller/).
"""
from __future__ import annotations

import ipaddress
import math
import re
import tomllib
from itertools import pairwise
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from controller.errors import BadInput
from devices.sections import DEVICE_KINDS, validate_section
from devices.sections import section_model as device_model


class Strict(BaseModel):
    # inf/nan are refused here too (load_config refuses them in every section, models or not)
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


DAY_S = 86_400.0
_LABEL = r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
HOSTNAME = re.compile(rf"(?:{_LABEL}\.)*{_LABEL}\.?")
SensorId = Annotated[str, Field(pattern=r"^[A-Za-z0-9_.-]{1,32}$")]  # a Zenoh key chunk: sensor/{id}


def endpoint_port(endpoint: str) -> str | None:
    """The port of a ``tcp/HOST:PORT`` (udp, tls, quic, ws) endpoint, as written; None for others."""
    m = re.fullmatch(r"(?:tcp|udp|tls|quic|ws)/.*:([^:/#\]]*)(?:#.*)?", endpoint)
    return None if m is None else m.group(1)


class BusConfig(Strict):
    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = ["tcp/127.0.0.1:7447"]
    connect: list[str] = []
    # an empty path meant no file: a deployment ran without its logins and access control
    config: str | None = Field(None, min_length=1, description="Zenoh JSON5 config file; overrides listen/connect")
    publish_contacts: bool = True

    @field_validator("listen", "connect")
    @classmethod
    def _ports(cls, endpoints: list[str], info) -> list[str]:
        # Zenoh takes tcp/127.0.0.1:99999 or :abc into its config and fails only as the session
        # opens: after the simulator had started and the ledger was made (an outside tester)
        for endpoint in endpoints:
            port, least = endpoint_port(endpoint), 0 if info.field_name == "listen" else 1
            if port is None:
                continue                     # Zenoh's own parse says what is wrong with the rest
            if not port.isdigit() or not least <= int(port) <= 65535:
                raise ValueError(f"{endpoint!r}: the port must be a number {least}..65535")
        return endpoints

    @model_validator(mode="after")
    def _a_client_connects(self) -> BusConfig:
        if self.mode == "client" and not self.connect and self.config is None:
            raise ValueError("mode = \"client\" listens nowhere and needs connect: the router's endpoint")
        return self


class StoreConfig(Strict):
    path: str = "var/fishfarm.db"


class ScadaConfig(Strict):
    """``[scada]``: the Modbus TCP server for SCADA (controller/scada). No section, no server."""
    enabled: bool = True
    listen: str = Field("127.0.0.1", min_length=1, max_length=255, description="address to listen on")
    port: int = Field(5020, ge=0, le=65535, description="0: any free port (logged)")
    unit: int = Field(1, ge=1, le=247, description="Modbus unit id answered; others get exception 0B")
    word_order: Literal["big", "little"] = Field("big", description="32-bit values: big = high word first")
    read_only: bool = Field(False, description="refuse every write (exception 02)")
    identity: str = Field("scada", pattern=r"^[A-Za-z0-9_.@-]{1,64}$",
                          description="the operator Modbus writes are audited as")
    idle_timeout_s: float = Field(60.0, gt=0, le=DAY_S, description="a connection silent this long is dropped")
    max_connections: int = Field(8, ge=1, le=1000, description="connections beyond are closed at once")
    refresh_s: float = Field(0.25, ge=0.01, le=60, description="wall seconds between snapshot refreshes")

    @field_validator("listen")
    @classmethod
    def _an_address(cls, listen: str) -> str:
        # "no such host!" was an alarm retried for good, not bad input
        if not (HOSTNAME.fullmatch(listen) or re.fullmatch(r"[0-9A-Fa-f:.]+", listen)):
            raise ValueError(f"{listen!r} is not an IP address or a host name")
        if re.fullmatch(r"[0-9.]+", listen) or ":" in listen:     # an address, then a real one
            try:                                                 # (999.1.1.1 was an alarm for good)
                ipaddress.ip_address(listen)
            except ValueError:
                raise ValueError(f"{listen!r} is not an IP address") from None
        return listen


class SurveySchedule(Strict):
    """A tank's ``survey = {every_days = 7, at = "10:00", pairs = 40}``: the rail robot surveys it
    every ``every_days`` days from ``at`` (farm local time) on, ``pairs`` stereo pairs at most."""
    every_days: int = Field(7, ge=1, le=365)
    at: str = Field("10:00", pattern=r"^([01][0-9]|2[0-3]):[0-5][0-9]$", description="HH:MM, farm local time")
    pairs: int = Field(40, ge=1, le=10_000)


class TankConfig(Strict):
    id: str = Field(pattern=r"^[A-Za-z0-9_-]{1,32}$")
    species: str = "sparus_aurata"
    stock: int = Field(gt=0, le=100_000_000)
    mean_weight_g: float = Field(gt=0, le=1_000_000)
    position_m: float = Field(ge=0, le=10_000, description="along the rail from home")
    sensors: list[SensorId] = Field(min_length=1)
    feeding_rate_pct: float | None = Field(None, gt=0, le=20,
                                           description="% body weight a day; default from species")
    water_temp_c: float | None = Field(None, ge=-5, le=40, description="this tank's water; default [feeding]'s")
    target_weight_g: float | None = Field(None, gt=0, le=1_000_000, description="harvest weight, for projections")
    survey: SurveySchedule | None = Field(None, description="scheduled weight surveys (none: on request only)")


class FeedingConfig(Strict):
    portion_g: float = Field(60.0, gt=0, le=10_000, description="largest portion served per demand")
    min_portion_g: float = Field(5.0, gt=0, le=10_000,
                                 description="below this a ration remainder is not served")
    food_box_m: float = Field(0.0, ge=0, le=10_000)
    hopper_capacity_g: float = Field(8000.0, gt=0, le=10_000_000)
    refill_below_g: float = Field(1500.0, ge=0, le=10_000_000)
    auger_rate_g_s: float = Field(12.0, gt=0, le=10_000, description="first guess; learned from the load cell")
    position_tolerance_m: float = Field(0.05, gt=0, le=10)
    move_timeout_s: float = Field(120.0, gt=0, le=DAY_S)
    dispense_timeout_s: float = Field(60.0, gt=0, le=DAY_S)
    refill_timeout_s: float = Field(120.0, gt=0, le=DAY_S)
    retry_backoff_s: list[Annotated[float, Field(ge=0, le=DAY_S)]] = Field([5.0, 15.0, 60.0, 300.0],
                                                                          min_length=1, max_length=100)
    demand_expiry_s: float = Field(600.0, gt=0, le=DAY_S, description="a demand not served by then is dropped")
    serve_within_s: float = Field(60.0, gt=0, le=DAY_S, description="aim: auger start this soon after a demand")
    plan_margin_s: float = Field(15.0, ge=0, le=DAY_S, description="planning keeps this much of the aim in hand "
                                 "for what travel estimates miss (docking, talking to the devices)")
    rail_speed_m_s: float = Field(1.0, gt=0, le=100, description="cruise speed, for planning the next stop")
    rail_accel_m_s2: float = Field(0.5, gt=0, le=100, description="acceleration, for planning the next stop")
    water_temp_c: float = Field(20.0, ge=-5, le=40, description="water temperature the feeding tables are read at "
                                "(without a thermometer, or while its reading is stale or faulty)")
    water_poll_s: float = Field(300.0, gt=0, le=86400, description="farm seconds between thermometer reads")
    water_max_age_s: float = Field(3600.0, gt=0, le=7 * 86400,
                                   description="a probe's last good reading older than this is not used")
    tables: list[str] = Field([], description="feeding charts (TOML, controller/feeding/feeding_table.py), "
                              "relative to farm.toml; a species without one is fed by its species.toml rows")
    survey_max_age_d: float = Field(14.0, gt=0, le=365, description="older surveys: the weight is projected")
    grading_cv_pct: float = Field(30.0, gt=0, le=200, description="weight CV above which a tank wants grading")
    growth_window_d: float = Field(56.0, gt=0, le=365, description="surveys pooled in the growth fit: those "
                                   "this many days before the newest (controller/growth.py)")
    growth_model: Literal["feed", "sgr"] = Field("feed", description="the growth fitted to the surveys: "
                                                 "feed given / FCR, or a constant SGR (controller/growth.py)")

    @model_validator(mode="after")
    def _portions_fit(self):
        if self.min_portion_g > self.portion_g:
            raise ValueError(f"min_portion_g ({self.min_portion_g:g}) is more than portion_g ({self.portion_g:g})")
        if self.refill_below_g >= self.hopper_capacity_g:
            raise ValueError(f"refill_below_g ({self.refill_below_g:g}) must be below hopper_capacity_g "
                             f"({self.hopper_capacity_g:g})")
        if self.water_poll_s >= self.water_max_age_s:
            raise ValueError(f"water_poll_s ({self.water_poll_s:g}) must be below water_max_age_s "
                             f"({self.water_max_age_s:g}): each reading would be too old before the next")
        return self


Point = tuple[Annotated[float, Field(ge=-100_000, le=100_000)], Annotated[float, Field(ge=-100_000, le=100_000)]]


class CleaningConfig(Strict):
    """``[cleaning]``: the pond cleaner (controller/cleaning). No section, no cleaner. Pond metres,
    x right / y up; the pond's geometry is checked as a whole by controller/cleaning/geometry.py."""
    outline: list[Point] = Field(min_length=3, max_length=10_000, description="the pond's edge, [x, y] corners")
    keepouts: list[list[Point]] = Field([], max_length=1000, description="drains, feeders: polygons to avoid")
    tower: str = Field(min_length=1, description="TOWER.json: the tower camera's homography (fishfarm calibrate tower)")
    dock: Point = Field(description="where the robot rests, [x, y]")
    brush_m: float = Field(0.5, gt=0, le=10, description="width the brush cleans")
    body_radius_m: float = Field(0.4, gt=0, le=10, description="the robot's radius: its centre keeps this off walls")
    cruise: float = Field(0.6, gt=0, le=1, description="thrust along the path, fraction of full")
    lookahead_m: float = Field(1.0, gt=0, le=50, description="pure pursuit's look-ahead")
    lost_after_s: float = Field(4.0, gt=0, le=3600, description="the float unseen this long: lost, thrusters stop")
    recover_after_s: float = Field(5.0, gt=0, le=3600,
                                   description="lost this long: back up slowly along the last ~2 m driven")
    autostart: bool = Field(False, description="at start, clean from the dock if the map is not complete")
    cell_m: float = Field(0.1, ge=0.01, le=5, description="coverage map cell")
    overlap: float = Field(0.05, ge=0, lt=0.5, description="share of the brush lanes overlap by")
    keepout_margin_m: float = Field(0.10, ge=0, le=5, description="the plan's room beyond body_radius_m round "
                                    "keep-outs (no wall stops the robot there; the geofence guards them)")
    mopup_max_m: float = Field(6.0, ge=0, le=10_000, description="after the lanes, at most this path (m) over "
                               "floor the map calls dirty (controller/cleaning/mopup.py); 0: no mop-up")
    mopup_max_s: float = Field(900.0, gt=0, le=86_400, description="and at most this many farm seconds")
    save_every_s: float = Field(5.0, gt=0, le=3600, description="farm seconds between saves of the map")
    publish_every_s: float = Field(1.0, gt=0, le=3600, description="farm seconds between cleaner/state besides changes")
    detection: dict[str, Any] = Field({}, alias="float",
                                      description="[cleaning.float]: the marker's detection (vision/float_detect.py)")


class SurveysConfig(Strict):
    """``[surveys]``: how the rail robot's survey stop runs (controller/surveys/stop.py)."""
    camera: str | None = Field(None, description="the stereo_camera device (default: the only one)")
    setup: Literal["underwater", "surface"] = "underwater"
    settle_s: float = Field(60.0, ge=0, le=3600, description="farm seconds the water settles before capture")
    pair_interval_s: float = Field(2.0, ge=0, le=3600, description="farm seconds at least between pairs")
    pairs: int = Field(40, ge=1, le=10_000, description="pairs of a survey started by an operator")
    stale_frames: int = Field(1, ge=0, le=100, description="frames dropped after settling: a camera's buffers "
                              "may hold ones taken before the carriage stopped")
    ci_pct: float = Field(2.0, gt=0, le=100, description="stop early once the mean weight's 95 % CI is within ±this")
    min_fish: int = Field(30, ge=2, le=100_000, description="fish measured before the CI may stop a survey")
    min_weighed_fish: int = Field(10, ge=1, le=100_000,
                                  description="fewest fish a survey counts to weigh its tank (rations, growth, "
                                  "figures); one with fewer is kept, published, warned of and tried again")
    probe_pairs: int = Field(8, ge=0, le=10_000,
                             description="pairs measured after which a visit counting fish at under half the "
                             "rate that weighs the tank (min_weighed_fish in its pairs) is cut short: recorded, "
                             "warned of and tried again as one that counted too few (0: never)")
    retry_s: float = Field(3600.0, gt=0, le=86_400 * 7,
                           description="farm seconds before a failed survey is tried again")
    floor_mm: float | None = Field(None, gt=0, le=100_000,
                                   description="surface setup: the tank floor's distance below the left camera, "
                                   "mm; fish shadows and debris on it are not counted as fish")
    out_dir: str = Field("var/surveys", min_length=1, description="each survey's OUT.json")

    @field_validator("floor_mm")
    @classmethod
    def _floor_is_the_surface_setup_s(cls, v, info):
        if v is not None and info.data.get("setup") != "surface":
            raise ValueError("the tank floor is the surface setup's (setup = \"surface\"): underwater cameras "
                             "would ignore it")
        return v


class Config(Strict):
    site: str = Field("demo", pattern=r"^[A-Za-z0-9_-]{1,64}$")
    utc_offset_h: float = Field(0.0, ge=-12, le=14, description="rations reset at local midnight")
    bus: BusConfig = BusConfig()
    store: StoreConfig = StoreConfig()
    scada: ScadaConfig | None = None
    feeding: FeedingConfig = FeedingConfig()
    demand: dict[str, Any] = {}
    tanks: list[TankConfig] = Field(min_length=1)
    devices: dict[str, dict[str, Any]] = {}
    sim: dict[str, Any] = {}
    stocks: dict[str, dict[str, Any]] = {}     # weight surveys' a, b per stock: controller/surveys/species.py
    cleaning: CleaningConfig | None = None
    surveys: SurveysConfig = SurveysConfig()
    path: str = "<config>"

    @field_validator("utc_offset_h")
    @classmethod
    def _a_zone_s_offset(cls, h: float) -> float:
        # the world's zones lie -12..+14 h in quarter hours (+5:45 Nepal): 5.123 is a typo
        if abs(h * 4 - round(h * 4)) > 1e-9:
            raise ValueError(f"{h:g} h is no time zone's offset: a whole hour, or a half or quarter past")
        return h

    @field_validator("tanks")
    @classmethod
    def _unique_tanks(cls, tanks):
        seen: set[str] = set()
        sensors: set[str] = set()
        for i, tank in enumerate(tanks):
            if tank.id in seen:
                raise ValueError(f"tank id {tank.id!r} appears twice (tanks.{i})")
            seen.add(tank.id)
            if len(set(tank.sensors)) < len(tank.sensors):
                twice = next(s for s in tank.sensors if tank.sensors.count(s) > 1)
                raise ValueError(f"sensor {twice!r} is listed twice in tank {tank.id!r} (tanks.{i})")
            for s in tank.sensors:
                if s in sensors:
                    raise ValueError(f"sensor {s!r} belongs to two tanks (tanks.{i})")
                sensors.add(s)
        return tanks

    @model_validator(mode="after")
    def _tanks_apart(self):
        # the robot "at" one tank would be at the other too: a portion for one lands in either
        near = 2 * self.feeding.position_tolerance_m
        placed = sorted((t.position_m, i) for i, t in enumerate(self.tanks))
        for (a, i), (b, j) in pairwise(placed):
            if b - a < near:
                k, other = max(i, j), min(i, j)
                raise ValueError(f"tanks.{k}.position_m puts tank {self.tanks[k].id!r} {b - a:g} m from tank "
                                 f"{self.tanks[other].id!r}, closer than twice feeding.position_tolerance_m "
                                 f"({near:g} m): the robot at one would be at both")
        return self

    @model_validator(mode="after")
    def _devices_known(self):
        for name, section in self.devices.items():
            if section.get("kind") not in DEVICE_KINDS:
                raise ValueError(f"devices.{name}.kind must be one of {', '.join(DEVICE_KINDS)}")
        return self

    def tank(self, tank_id: str) -> TankConfig:
        for t in self.tanks:
            if t.id == tank_id:
                return t
        raise KeyError(tank_id)



def load_config(path: str | Path) -> Config:
    path = Path(path)
    where = str(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8-sig"))    # a Windows editor's BOM is no fault
    except FileNotFoundError:
        raise BadInput(where, None, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInput(where, None, f"cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise BadInput(where, None, f"not valid TOML: {exc}") from None
    if "tank" in raw and "tanks" not in raw:
        raw["tanks"] = raw.pop("tank")
    for key, value in _numbers(raw):
        if not math.isfinite(value):
            raise BadInput(where, key, f"must be a finite number, not {value}")
    cfg = validate_section(Config, {**raw, "path": where}, where)
    for name, section in cfg.devices.items():
        prefix = f"devices.{name}"
        try:
            model = device_model(section["kind"], str(section.get("driver")))
        except ValueError as exc:
            raise BadInput(where, f"{prefix}.driver", str(exc)) from None
        validate_section(model, section, where, prefix)
    return cfg


def _numbers(value, key: str = ""):
    """(key.path, float) for every float in a parsed TOML document: TOML has inf and nan, and no
    section of ours means either, whether or not a model checks that key."""
    if isinstance(value, float):
        yield key, value
    elif isinstance(value, dict):
        for k, v in value.items():
            yield from _numbers(v, f"{key}.{k}" if key else str(k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _numbers(v, f"{key}.{i}")


def load_toml(path: str | Path) -> dict:
    """Any other TOML file of ours (species.toml), with the same one-line errors."""
    try:
        raw = tomllib.loads(Path(path).read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        raise BadInput(str(path), None, "no such file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise BadInput(str(path), None, f"cannot read: {exc}") from None
    for key, value in _numbers(raw):
        if not math.isfinite(value):
            raise BadInput(str(path), key, f"must be a finite number, not {value}")
    return raw
