"""The simulated water: its cycles peak where its parameters say, and the twin's registers say it
in the register map's words."""
import math

import numpy as np
import pytest

from devices.clock import ManualClock
from devices.errors import BadInput
from devices.sim.thermometer import SimThermometer, WaterModel, WaterParams

DAY = 86400.0
YEAR0 = 1_767_225_600.0          # 2026-01-01 00:00 UTC


def test_the_year_peaks_on_its_warmest_day_and_the_day_at_its_warmest_hour():
    p = WaterParams(mean_c=20, seasonal_amp_c=4, warmest_day=200, diurnal_amp_c=1, warmest_hour=15,
                    utc_offset_h=2, noise_c=0)
    water = WaterModel(p)
    days = YEAR0 + np.arange(0, 365) * DAY + 13 * 3600          # 15:00 local every day
    temps = [water.true_c("T1", t) for t in days]
    assert abs(int(np.argmax(temps)) - 200) <= 1
    assert max(temps) == pytest.approx(25.0, abs=0.01) and min(temps) == pytest.approx(17.0, abs=0.01)
    hours = YEAR0 + 200 * DAY + np.arange(0, 24 * 60) * 60.0    # that day, minute by minute (UTC)
    day = [water.true_c("T1", t) for t in hours]
    assert int(np.argmax(day)) // 60 == 13                       # 15:00 local is 13:00 UTC
    assert max(day) - min(day) == pytest.approx(2.0, abs=0.01)


def test_offsets_and_noise():
    water = WaterModel(WaterParams(offsets_c={"T5": 1.5}, noise_c=0.1, seed=3))
    t = YEAR0 + 100 * DAY
    assert water.true_c("T5", t) - water.true_c("T1", t) == pytest.approx(1.5)
    reads = np.array([water.read_c("T1", t) for _ in range(4000)]) - water.true_c("T1", t)
    assert abs(reads.mean()) < 0.01 and reads.std() == pytest.approx(0.1, rel=0.1)


def test_the_twin_shows_signed_tenths_and_fault_codes():
    clock = ManualClock(YEAR0 + 10 * DAY)
    sim = SimThermometer({"mean_c": 2.0, "seasonal_amp_c": 5.0, "diurnal_amp_c": 0, "noise_c": 0,
                          "faults": {"T3": "short"}}, clock, {"T1": 0, "T3": 4})
    words = sim.registers(clock.now())
    expect = round(sim.water.true_c("T1", clock.now()) * 10)
    assert expect < 0 and words[0] == expect + 65536             # winter: below zero, two's complement
    assert words[4] == 0x8000
    sim.set_fault("T3", "open")
    assert sim.registers(clock.now())[4] == 0x7FFF
    sim.set_fault("T3", None)
    assert sim.registers(clock.now())[4] not in (0x7FFF, 0x8000)


def test_bad_water_parameters_name_their_key():
    with pytest.raises(BadInput, match="sim.thermometer.diurnal_amp_c"):
        SimThermometer({"diurnal_amp_c": -1}, ManualClock(0.0), {"T1": 0})
    with pytest.raises(BadInput, match="sim.thermometer.sesonal_amp_c.*unknown key"):
        SimThermometer({"sesonal_amp_c": 1}, ManualClock(0.0), {"T1": 0})
    assert math.isfinite(WaterModel(WaterParams()).true_c("x", 0.0))
