"""Config sections validated below controller/: one line naming file, key and fault; the backend's model."""
import pytest
from pydantic import BaseModel, ConfigDict, Field

import controller.config
import controller.errors
from devices.errors import BadInput
from devices.rail.can_drive import CanRailDrive
from devices.sections import section_model, validate_section
from devices.sim import SimDispenserSection


class Part(BaseModel):
    model_config = ConfigDict(extra="forbid")
    rate_g_s: float = Field(10.0, gt=0)
    nested: dict[str, int] = {}


@pytest.mark.parametrize("data, line", [
    ({"rate": 1}, "farm.toml: sim.part.rate: unknown key"),
    ({"rate_g_s": 0}, "farm.toml: sim.part.rate_g_s: Input should be greater than 0"),
    ({"nested": {"a": "x"}}, "farm.toml: sim.part.nested.a: Input should be a valid integer"),
    ([], "farm.toml: sim.part: Input should be a table"),
    # nothing converted behind the operator's back (a probe's `port = true` bound port 1)
    ({"rate_g_s": True}, "farm.toml: sim.part.rate_g_s: Input should be a valid number"),
    ({"rate_g_s": "10"}, "farm.toml: sim.part.rate_g_s: Input should be a valid number"),
    ({"nested": {"a": 2.0}}, "farm.toml: sim.part.nested.a: Input should be a valid integer"),
    ({"nested": {"a": False}}, "farm.toml: sim.part.nested.a: Input should be a valid integer"),
])
def test_a_bad_section_is_one_line_naming_file_key_and_fault(data, line):
    with pytest.raises(BadInput) as err:
        validate_section(Part, data, "farm.toml", "sim.part")
    assert str(err.value) == line


class Flags(BaseModel):
    model_config = ConfigDict(extra="forbid")
    on: bool = False
    pair: tuple[float, float] = (0.0, 1.0)
    names: list[str] = []


@pytest.mark.parametrize("data, fault", [({"on": "yes"}, "on: Input should be a valid boolean"),
                                         ({"on": 0}, "on: Input should be a valid boolean"),
                                         ({"names": ["a", 1]}, "names.1: Input should be a valid string")])
def test_booleans_and_strings_are_taken_only_as_themselves(data, fault):
    with pytest.raises(BadInput) as err:
        validate_section(Flags, data, "farm.toml")
    assert str(err.value) == f"farm.toml: {fault}"


def test_an_array_still_makes_a_tuple_and_an_integer_a_float():
    assert validate_section(Flags, {"pair": [1, 2.5], "on": True}, "farm.toml") == Flags(pair=(1.0, 2.5), on=True)
    assert validate_section(Part, {"rate_g_s": 3}, "farm.toml").rate_g_s == 3.0


def test_the_controller_raises_and_catches_the_same_bad_input():
    assert controller.errors.BadInput is BadInput
    assert controller.config.validate_section is validate_section


def test_a_section_model_is_the_backend_s_own():
    assert section_model("rail", "can") is CanRailDrive.Config
    assert section_model("dispenser", "sim") is SimDispenserSection
    with pytest.raises(ValueError, match="driver must be one of sim, modbus"):
        section_model("dispenser", "tcp")
    with pytest.raises(ValueError, match="kind must be one of contacts, rail, dispenser"):
        section_model("pump", "sim")


def test_a_whole_section_of_the_wrong_type_is_named_once():
    with pytest.raises(BadInput) as err:
        validate_section(Part, 5, "farm.toml")
    assert str(err.value) == "farm.toml: (top level): Input should be a table"


@pytest.mark.parametrize("kind, driver, data, fault", [
    # each was taken, and failed only once the simulator or the driver was up (an internal error,
    # an alarm retried for good, or OpenCV warnings flooding stderr)
    ("dispenser", "sim", {"port": -1}, "devices.d.port: Input should be greater than or equal to 0"),
    ("dispenser", "sim", {"unit": -3}, "devices.d.unit: Input should be greater than or equal to 0"),
    ("rail", "sim", {"node_id": 999}, "devices.d.node_id: Input should be less than or equal to 127"),
    ("thermometer", "sim", {"probes": {"T1": 70000}}, "devices.d.probes: probe 'T1': channel 70000 outside"),
    ("thermometer", "sim", {"probes": {"supply": -1}}, "devices.d.probes: probe 'supply': channel -1 outside"),
    ("dispenser", "modbus", {"host": ""}, "devices.d.host: String should have at least 1 character"),
    ("contacts", "serial", {"port": ""}, "devices.d.port: String should have at least 1 character"),
    ("rail", "can", {"channel": "x", "interface": "bogus"}, "devices.d.interface: interface must be one of"),
    ("rail", "can", {"channel": "x", "interface": "virtual", "status_timeout_s": 1e12},
     "devices.d.status_timeout_s: Input should be less than or equal to 60"),
    ("tower_camera", "capture", {"source": " "}, "devices.d.source: empty"),
])
def test_device_sections_refuse_what_their_device_cannot_be(kind, driver, data, fault):
    with pytest.raises(BadInput) as err:
        validate_section(section_model(kind, driver), {"kind": kind, "driver": driver, **data}, "farm.toml",
                         "devices.d")
    assert str(err.value).startswith(f"farm.toml: {fault}"), str(err.value)
