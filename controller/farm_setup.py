"""What the controller checks of a farm as a whole before anything starts, and how it builds a
device from its config section (through its kind's ``BACKENDS`` table)."""
from __future__ import annotations

import importlib
import math
import os
import tempfile
from pathlib import Path

from controller.config import Config, endpoint_port, validate_section
from controller.errors import BadInput
from controller.feeding.dispensing import FULL_SHARE, UNMEASURED
from controller.feeding.rations import load_tables
from controller.water import check_thermometer
from devices.sections import backends as device_backends

CLEANER_KINDS = ("thrusters", "tower_camera")


def check_hopper(cfg: Config) -> None:
    """A full hopper holds a portion with room for the auger's overshoot (its most, while its rate
    is a guess): else no refill is ever enough and the robot goes back to the box for good."""
    f = cfg.feeding
    most = FULL_SHARE * f.hopper_capacity_g / (1 + UNMEASURED)
    if f.portion_g > most:
        raise BadInput(cfg.path, "feeding.portion_g",
                       f"{f.portion_g:g} g does not fit a full hopper ({FULL_SHARE:.0%} of hopper_capacity_g "
                       f"{f.hopper_capacity_g:g} g) with room for the auger's overshoot ({UNMEASURED:.0%} until its "
                       f"rate is measured): at most {math.floor(most):g} g")


def check_stocks(cfg: Config, species: dict) -> None:
    """``[stocks.NAME]``: each one's keys, its species and its a, b as ``survey --stock`` checks
    them, though only that command uses them (a stock run took, a survey refused)."""
    from controller.feeding.rations import species_file
    from controller.surveys.species import StockSection, stock_law, survey_species
    for name, section in cfg.stocks.items():
        stock = validate_section(StockSection, section, cfg.path, f"stocks.{name}")
        if stock.species not in species:
            raise BadInput(cfg.path, f"stocks.{name}.species",
                           f"unknown species {stock.species!r} (known: {', '.join(sorted(species))})")
        stock_law(survey_species(stock.species, species_file(cfg.path)), stock, cfg.path, name)


def build_device(name: str, section: dict, clock, where: str):
    kind = section["kind"]
    backends = device_backends(kind)
    module, attr = backends[section["driver"]].split(":")
    cls = getattr(importlib.import_module(module), attr)
    return cls(name, validate_section(cls.Config, section, where, f"devices.{name}"), clock)


def check_tank_species(cfg: Config, species: dict) -> None:
    """Every tank's species is in species.toml: the ration, the figures and the report read its
    rows, and a misspelt one would be read as another farm's fish (or as none)."""
    for i, tank in enumerate(cfg.tanks):
        if tank.species not in species:
            raise BadInput(cfg.path, f"tanks.{i}.species",
                           f"unknown species {tank.species!r} (known: {', '.join(sorted(species))})")


def check_species_file(cfg: Config) -> None:
    """``check_tank_species`` against the species.toml the farm uses (``species_file``): what the
    commands that only read the ledger check, as ``run`` does."""
    from controller.feeding.rations import load_species, species_file
    check_tank_species(cfg, load_species(species_file(cfg.path)))


def check_ports(cfg: Config) -> None:
    """No two of the farm's own servers on one port: a simulated dispenser given [scada]'s port took
    it, and the SCADA server only alarmed (an outside tester). Ports 0 (any free one) aside."""
    taken: dict[int, str] = {}
    wanted = []
    if cfg.scada is not None and cfg.scada.enabled:
        wanted.append((cfg.scada.port, "scada.port"))
    for i, endpoint in enumerate(cfg.bus.listen if cfg.bus.config is None else []):
        port = endpoint_port(endpoint)
        if port is not None and port.isdigit():
            wanted.append((int(port), f"bus.listen.{i}"))
    for name, section in cfg.devices.items():
        if section.get("driver") == "sim" and isinstance(section.get("port"), int):
            wanted.append((section["port"], f"devices.{name}.port"))
    for port, key in wanted:
        if port and port in taken:
            raise BadInput(cfg.path, key, f"port {port} is {taken[port]}'s too: two servers cannot listen on one port")
        taken.setdefault(port, key)


def check_survey_dir(cfg: Config) -> None:
    """``surveys.out_dir`` is a directory, or one can be made there (nothing is made yet): a file
    or /proc was taken, and each survey's OUT.json would have failed at its end."""
    out = Path(cfg.surveys.out_dir)
    if out.exists():
        if not out.is_dir():
            raise BadInput(cfg.path, "surveys.out_dir", f"{out}: a file, not a directory")
        return
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    why = None if parent.is_dir() else f"{parent} is a file"
    if why is None:
        try:      # tried for real: root passes access() in /proc, where nothing can be made
            os.rmdir(tempfile.mkdtemp(prefix=".fishfarm-trial-", dir=parent))
        except OSError as exc:
            why = f"nothing can be made in {parent}: {exc.strerror or exc}"
    if why is not None:
        raise BadInput(cfg.path, "surveys.out_dir", f"{out}: {why}")


def check_farm(cfg: Config, species: dict) -> None:
    """What the sections cannot check alone: every tank's species is known, the feeding charts are
    for known species, a portion fits the hopper, the stocks' sections, one device of each kind."""
    check_tank_species(cfg, species)
    load_tables(cfg, species)
    check_hopper(cfg)
    check_stocks(cfg, species)
    for kind in ("contacts", "rail", "dispenser"):
        found = [name for name, s in cfg.devices.items() if s["kind"] == kind]
        if len(found) != 1:
            raise BadInput(cfg.path, "devices", f"the feeding robot needs exactly one {kind} device, "
                                                f"found {len(found)}")
    check_thermometer(cfg)
    check_ports(cfg)
    check_survey_dir(cfg)
    sim_cameras = [n for n, s in cfg.devices.items() if s["kind"] == "stereo_camera" and s["driver"] == "sim"]
    if cfg.surveys.setup == "surface" and sim_cameras:
        # its surveys would count a fish or two in scenes drawn for the other setup, and fall back
        # to the configured weights for good, with a "few fish" warning that blames the water
        raise BadInput(cfg.path, "surveys.setup", f"\"surface\", but devices.{sim_cameras[0]} is simulated and "
                                                  "renders underwater scenes only: survey a surface setup on "
                                                  "real cameras (driver = \"capture\")")
    for kind in CLEANER_KINDS:
        found = [name for name, s in cfg.devices.items() if s["kind"] == kind]
        if cfg.cleaning is None and found:
            raise BadInput(cfg.path, f"devices.{found[0]}", f"a {kind} device needs a [cleaning] section")
        if cfg.cleaning is not None and len(found) != 1:
            raise BadInput(cfg.path, "devices", f"the pond cleaner needs exactly one {kind} device, "
                                                f"found {len(found)}")
