"""What the controller checks of a farm as a whole before anything starts, and how it builds a
device from its config section (through its kind's ``BACKENDS`` table)."""
from __future__ import annotations

import importlib

from controller.config import Config, validate_section
from controller.errors import BadInput
from controller.water import check_thermometer
from devices.sections import backends as device_backends

CLEANER_KINDS = ("thrusters", "tower_camera")


def build_device(name: str, section: dict, clock, where: str):
    kind = section["kind"]
    backends = device_backends(kind)
    module, attr = backends[section["driver"]].split(":")
    cls = getattr(importlib.import_module(module), attr)
    return cls(name, validate_section(cls.Config, section, where, f"devices.{name}"), clock)


def check_farm(cfg: Config, species: dict) -> None:
    """What the sections cannot check alone: every tank's species is known, one device of each kind."""
    for i, tank in enumerate(cfg.tanks):
        if tank.species not in species:
            raise BadInput(cfg.path, f"tanks.{i}.species",
                           f"unknown species {tank.species!r} (known: {', '.join(sorted(species))})")
    for kind in ("contacts", "rail", "dispenser"):
        found = [name for name, s in cfg.devices.items() if s["kind"] == kind]
        if len(found) != 1:
            raise BadInput(cfg.path, "devices", f"the feeding robot needs exactly one {kind} device, "
                                                f"found {len(found)}")
    check_thermometer(cfg)
    for kind in CLEANER_KINDS:
        found = [name for name, s in cfg.devices.items() if s["kind"] == kind]
        if cfg.cleaning is None and found:
            raise BadInput(cfg.path, f"devices.{found[0]}", f"a {kind} device needs a [cleaning] section")
        if cfg.cleaning is not None and len(found) != 1:
            raise BadInput(cfg.path, "devices", f"the pond cleaner needs exactly one {kind} device, "
                                                f"found {len(found)}")
