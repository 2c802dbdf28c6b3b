"""Config sections: each part validates its own section, and a fault is one line naming it.

Shared by devices/ (a device's section, the simulated world's ``[sim.*]`` sections) and
controller/ (farm.toml as a whole), so it lives at the bottom of the layers: devices/ never
imports controller/. ``controller.config`` re-exports ``validate_section``.
"""
from __future__ import annotations

import importlib
import json
import re
from typing import Any

from pydantic import BaseModel, ValidationError

from devices.errors import BadInput

DEVICE_KINDS = ("contacts", "rail", "dispenser", "thrusters", "tower_camera", "thermometer", "stereo_camera")
PACKAGES = {"tower_camera": "devices.camera", "stereo_camera": "devices.stereo"}
"""The package of a kind whose name is not its package's (default: ``devices.<kind>``)."""


def backends(kind: str) -> dict[str, str]:
    """A kind's ``BACKENDS`` table: driver -> ``module:Class``."""
    return dict(importlib.import_module(PACKAGES.get(kind, f"devices.{kind}")).BACKENDS)


# a check across keys whose message begins with the key at fault: a dotted path, or a key "must ..."
_NAMED = re.compile(r"^([A-Za-z_][\w-]*(?:\.[\w-]+)+) (.+)$|^([A-Za-z_]\w*) (must .+)$", re.DOTALL)


def _loc(err: dict) -> str:
    return ".".join(str(p) for p in err["loc"])


def validate_section(model: type[BaseModel], data: Any, where: str, prefix: str = ""):
    """Validate ``data`` against ``model``; on failure raise BadInput naming file, key and reason.

    Strictly, as JSON: a TOML ``true`` is no number (``port = true`` bound port 1), a string is no
    number nor a boolean (``read_only = "yes"``), a whole float is no count (``stock = 2400.0``),
    while an array still makes a tuple and an integer a float. Data JSON cannot carry (a TOML
    date, a NaN) is validated as Python objects: refused where it is read."""
    try:
        text = json.dumps(data, allow_nan=False)
    except (TypeError, ValueError):
        text = None
    try:
        return model.model_validate(data) if text is None else model.model_validate_json(text, strict=True)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(p for p in (prefix, _loc(err)) if p) or "(top level)"
        msg = err["msg"]
        named = _NAMED.match(msg[len("Value error, "):] if msg.startswith("Value error, ") else "")
        if not err["loc"] and named:     # a check across keys that names the one at fault first
            key = ".".join(p for p in (prefix, named.group(1) or named.group(3)) if p)
            msg = "Value error, " + (named.group(2) or named.group(4))
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        elif msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        msg = msg.replace("Input should be an object", "Input should be a table")    # TOML's word
        raise BadInput(where, key, msg) from None


def section_model(kind: str, driver: str) -> type[BaseModel]:
    """The section model of a device backend, looked up through its kind's BACKENDS table;
    ``driver = "sim"`` is the simulated twin's section (devices/sim). ValueError names the choices."""
    if kind not in DEVICE_KINDS:
        raise ValueError(f"kind must be one of {', '.join(DEVICE_KINDS)}")
    table = backends(kind)
    if driver == "sim":
        return importlib.import_module("devices.sim").SIM_SECTIONS[kind]
    if driver not in table:
        raise ValueError(f"driver must be one of sim, {', '.join(table)}")
    mod, attr = table[driver].split(":")
    return getattr(importlib.import_module(mod), attr).Config
