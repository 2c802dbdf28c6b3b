"""The water thermometer's coordinator on the real driver and the simulated transmitter, under a
manual clock: which temperature each tank's ration is read at, and what an operator is told."""
import asyncio

import pytest

from controller.alarms import Alarms
from controller.config import load_config
from controller.errors import BadInput
from controller.feeding.rations import Rations, load_species
from controller.store import Store
from controller.water import WaterTemperatures, check_thermometer
from devices.clock import ManualClock
from devices.sim.thermometer import SimThermometer
from devices.thermometer.modbus_thermometer import Config, ModbusThermometer

T0 = 1_780_000_000.0
PROBES = {"supply": 0, "T1": 1, "T5": 2}
WATER = {"mean_c": 18.0, "seasonal_amp_c": 0.0, "diurnal_amp_c": 0.0, "noise_c": 0.0, "offsets_c": {"T5": 3.0}}


class Published(list):
    def __call__(self, suffix, payload, reliable=False):
        self.append((suffix, payload))


def farm(tmp_path, probes=PROBES, water=WATER, **feeding):
    cfg = load_config("config/farm.toml")
    cfg = cfg.model_copy(update={"feeding": cfg.feeding.model_copy(update=feeding)})
    clock = ManualClock(T0)
    store = Store(tmp_path / "w.db")
    alarms = Alarms(store, Published(), clock)
    sim = SimThermometer(water, clock, probes)
    return cfg, clock, store, alarms, sim


def run(body):
    asyncio.run(asyncio.wait_for(body(), 30))


def test_a_tank_reads_its_own_probe_else_the_supply_and_rations_follow(tmp_path):
    cfg, clock, store, alarms, sim = farm(tmp_path)
    rations = Rations(cfg, load_species(), store)
    configured = rations.plan("T2", T0).grams               # at [feeding] water_temp_c (22 °C)

    async def body():
        await sim.start()
        th = ModbusThermometer("water", Config(kind="thermometer", driver="modbus", port=sim.port,
                                               probes=PROBES), clock)
        await th.open()
        fresh = []
        water = WaterTemperatures(cfg, th, clock, alarms, on_fresh=fresh.extend)
        rations.water = water
        assert water.temperature("T1").source == "config"      # nothing read yet
        assert await water.poll_once()
        assert sorted(fresh) == sorted(t.id for t in cfg.tanks)     # every tank measured now
        assert (water.temperature("T1").celsius, water.temperature("T1").probe) == (18.0, "T1")
        assert (water.temperature("T5").celsius, water.temperature("T5").probe) == (21.0, "T5")
        assert (water.temperature("T3").celsius, water.temperature("T3").probe) == (18.0, "supply")
        assert rations.water_temp_c("T5") == 21.0
        assert await water.poll_once() and len(fresh) == len(cfg.tanks)   # not fresh twice
        await th.close()
        await sim.stop()
    run(body)
    assert rations.plan("T2", T0).grams != pytest.approx(configured)   # the chart read at 18 °C, not 22


def test_a_stale_or_faulty_probe_falls_back_to_the_config_and_is_alarmed_once(tmp_path):
    cfg, clock, store, alarms, sim = farm(tmp_path, water_max_age_s=600.0)

    async def body():
        await sim.start()
        th = ModbusThermometer("water", Config(kind="thermometer", driver="modbus", port=sim.port,
                                               probes=PROBES), clock)
        await th.open()
        water = WaterTemperatures(cfg, th, clock, alarms)
        await water.poll_once()
        sim.set_fault("T1", "open")
        for _ in range(3):
            clock.advance(100.0)
            await water.poll_once()
        assert water.temperature("T1").source == "sensor"       # its last good reading, 300 s old
        clock.advance(301.0)
        assert water.temperature("T1").source == "config"       # older than water_max_age_s
        own = cfg.tank("T1").water_temp_c
        assert water.temperature("T1").celsius == (own if own is not None else cfg.feeding.water_temp_c)
        standing = [a for a in alarms.listing() if a["source"] == "water/T1"]
        assert len(standing) == 1 and standing[0]["count"] == 1 and "open" in standing[0]["text"]
        # what it says is what the rations did: the last good reading while fresh (it said the config's)
        assert "its last good reading for up to 600 s, then the configured temperature" in standing[0]["text"]
        sim.set_fault("T1", None)
        await water.poll_once()
        assert water.temperature("T1").source == "sensor"
        assert not any(a["source"] == "water/T1" and a["active"] for a in alarms.listing())
        await sim.stop()                                         # the transmitter goes away
        assert not await water.poll_once() and not await water.poll_once()
        lost = [a for a in alarms.listing() if a["source"] == "device/water"]
        assert len(lost) == 1 and lost[0]["active"]
        assert water.snapshot()["T1"]["fault"] is None
        await th.close()
    run(body)


def test_without_a_thermometer_the_config_is_the_temperature(tmp_path):
    cfg, clock, store, alarms, _ = farm(tmp_path)
    water = WaterTemperatures(cfg, None, clock, alarms)
    assert water.temperature("T1").source == "config" and water.probe_of("T1") is None
    assert water.temperature("T1").celsius == cfg.feeding.water_temp_c


@pytest.mark.parametrize("devices, key", [
    ({"a": {"kind": "thermometer", "driver": "sim", "probes": {"T1": 0}},
      "b": {"kind": "thermometer", "driver": "sim", "probes": {"T2": 0}}}, "devices.b"),
    ({"a": {"kind": "thermometer", "driver": "sim", "probes": {"T99": 0}}}, "devices.a.probes.T99")])
def test_farm_level_thermometer_faults_name_their_key(devices, key):
    cfg = load_config("config/farm.toml")
    cfg = cfg.model_copy(update={"devices": {k: v for k, v in cfg.devices.items() if v["kind"] != "thermometer"}
                                 | devices})
    with pytest.raises(BadInput, match=key.replace(".", r"\.")):
        check_thermometer(cfg)


@pytest.mark.parametrize("field", ["offsets_c", "faults"])
def test_the_simulated_water_names_only_the_thermometer_s_probes(field):
    """An outside tester: ``offsets_c = {T55 = 1.5}`` (no tank, no probe) was taken and never used."""
    cfg = load_config("config/farm.toml")
    value = 1.5 if field == "offsets_c" else "open"
    bad = cfg.model_copy(update={"sim": {**cfg.sim, "thermometer": {field: {"T55": value}}}})
    with pytest.raises(BadInput, match=rf"sim\.thermometer\.{field}\.T55: not a probe"):
        check_thermometer(bad)
    probe = next(iter(next(s for s in cfg.devices.values() if s["kind"] == "thermometer")["probes"]))
    check_thermometer(cfg.model_copy(update={"sim": {**cfg.sim, "thermometer": {field: {probe: value}}}}))
