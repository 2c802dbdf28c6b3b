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
    ({"nested": {"a": "x"}}, "farm.toml: sim.part.nested.a: Input should be a valid integer, "
                             "unable to parse string as an integer"),
    ([], "farm.toml: sim.part: Input should be a valid dictionary or instance of Part"),
])
def test_a_bad_section_is_one_line_naming_file_key_and_fault(data, line):
    with pytest.raises(BadInput) as err:
        validate_section(Part, data, "farm.toml", "sim.part")
    assert str(err.value) == line


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
    assert str(err.value) == "farm.toml: (top level): Input should be a valid dictionary or instance of Part"
