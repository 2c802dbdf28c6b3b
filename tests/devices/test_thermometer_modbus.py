"""The thermometer's Modbus driver against a transmitter that is not our water model: a plain
pymodbus server whose input registers hold words written from the register map's own words
(signed tenths of a degree, 0x7FFF open, 0x8000 short), and against the simulated twin."""
import asyncio
import contextlib
import time

import pytest
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from devices.clock import ManualClock
from devices.errors import BadInput, DeviceTimeout, LinkDown
from devices.sections import section_model, validate_section
from devices.sim.thermometer import SimThermometer
from devices.thermometer.modbus_thermometer import Config, ModbusThermometer

T0 = 1_780_000_000.0


def config(port: int, probes: dict[str, int], **kw) -> Config:
    return Config(kind="thermometer", driver="modbus", port=port, probes=probes, **kw)


@contextlib.asynccontextmanager
async def transmitter(words: dict[int, int], first: int = 1, hang: bool = False):
    """A bare transmitter: ``words`` register address -> value, nothing else behind it."""
    regs = [0] * 64
    for address, value in words.items():
        regs[address - first] = value
    device = SimDevice(1, simdata=[SimData(first, values=regs, datatype=DataType.REGISTERS, readonly=True)])
    server = ModbusTcpServer(device, address=("127.0.0.1", 0),
                             trace_pdu=(lambda sending, pdu: pdu if sending else None) if hang else None)
    await server.serve_forever(background=True)
    try:
        yield server.transport.sockets[0].getsockname()[1]
    finally:
        await server.shutdown()


def run(coro):
    asyncio.run(asyncio.wait_for(coro, 30))


@pytest.mark.parametrize("word, celsius, fault", [
    (0, 0.0, None), (215, 21.5, None), (1, 0.1, None), (0xFFFF, -0.1, None), (0xFF9C, -10.0, None),
    (450, 45.0, None), (451, None, "range"), (0xFF9B, None, "range"), (0x7FFF, None, "open"),
    (0x8000, None, "short"), (0x7FFE, None, "range")])
def test_every_word_of_the_map_reads_as_the_map_says(word, celsius, fault):
    async def main():
        async with transmitter({1: word}) as port:
            async with ModbusThermometer("water", config(port, {"T1": 0}), ManualClock(T0)) as th:
                r = (await th.read())["T1"]
        assert (r.celsius, r.fault) == (pytest.approx(celsius) if celsius is not None else None, fault)
    run(main())


def test_channels_apart_are_read_in_one_request_each_from_its_own_register():
    async def main():
        words = {100 + 3: 180, 100 + 7: 0x7FFF, 100 + 12: 0xFFEC}
        async with transmitter(words, first=100) as port:
            cfg = config(port, {"T4": 3, "T5": 7, "supply": 12}, first_register=100)
            async with ModbusThermometer("water", cfg, ManualClock(T0)) as th:
                got = await th.read()
                assert th.probes == ("T4", "T5", "supply")
        assert {k: (v.celsius, v.fault) for k, v in got.items()} == {
            "T4": (18.0, None), "T5": (None, "open"), "supply": (-2.0, None)}
    run(main())


def test_a_span_set_for_warm_water_calls_cold_readings_out_of_range():
    async def main():
        async with transmitter({1: 150, 2: 100}) as port:
            cfg = config(port, {"T1": 0, "T2": 1}, span_c=(12.0, 35.0))
            async with ModbusThermometer("water", cfg, ManualClock(T0)) as th:
                got = await th.read()
        assert (got["T1"].celsius, got["T2"].fault) == (15.0, "range")
    run(main())


def test_nobody_listening_is_link_down_and_silence_is_a_timeout():
    async def main():
        async with transmitter({1: 200}) as port:
            pass                                                  # closed: the port is free again
        with pytest.raises(LinkDown):
            await ModbusThermometer("water", config(port, {"T1": 0}), ManualClock(T0)).open()
        async with transmitter({1: 200}, hang=True) as port:
            th = ModbusThermometer("water", config(port, {"T1": 0}, timeout_s=0.2, retries=0), ManualClock(T0))
            await th.open()
            with pytest.raises((DeviceTimeout, LinkDown)):
                await th.read()
            await th.close()
            await th.close()                                     # twice is harmless
    run(main())


def test_the_driver_reconnects_on_the_next_read_after_the_transmitter_restarts():
    async def main():
        clock = ManualClock(T0)
        sim = SimThermometer({"noise_c": 0.0}, clock, {"T1": 0})
        await sim.start()
        th = ModbusThermometer("water", config(sim.port, {"T1": 0}), clock)
        await th.open()
        first = (await th.read())["T1"].celsius
        await sim.stop()
        with pytest.raises(LinkDown):
            await th.read()
        await sim.start()                                        # same port, same water
        assert (await th.read())["T1"].celsius == first
        await th.close()
        await sim.stop()
    run(main())


@pytest.mark.parametrize("probes, fault", [
    ({}, "at least one probe"), ({"T1": 64}, "outside 0..63"), ({"T1": -1}, "outside"),
    ({"T1": 2, "T2": 2}, "share channel 2")])
def test_bad_probe_tables_are_refused_by_name(probes, fault):
    with pytest.raises(BadInput, match=fault) as e:
        validate_section(Config, {"kind": "thermometer", "driver": "modbus", "probes": probes}, "farm.toml",
                         "devices.water")
    assert "devices.water.probes" in str(e.value)


def test_unknown_keys_and_sections_name_themselves():
    with pytest.raises(BadInput, match="devices.water.chanels.*unknown key"):
        validate_section(section_model("thermometer", "modbus"),
                         {"kind": "thermometer", "driver": "modbus", "probes": {"T1": 0}, "chanels": 3},
                         "farm.toml", "devices.water")
    with pytest.raises(BadInput, match="devices.water.probes"):
        validate_section(section_model("thermometer", "sim"), {"kind": "thermometer", "driver": "sim"},
                         "farm.toml", "devices.water")


@pytest.mark.parametrize("connect_timeout_s, connects", [(None, True), (0.2, False)])
def test_a_connect_has_its_own_bound_not_a_reply_s(connect_timeout_s, connects):
    """The loop held as the handshake starts (a busy machine): a reply's 0.2 s bound once read a
    live transmitter as down; the connect waits ``connect_timeout_s`` (3 s unless set)."""
    async def main():
        async with transmitter({1: 215}) as port:
            extra = {} if connect_timeout_s is None else {"connect_timeout_s": connect_timeout_s}
            th = ModbusThermometer("water", config(port, {"T1": 0}, timeout_s=0.2, retries=0, **extra),
                                   ManualClock(T0))
            asyncio.get_running_loop().call_soon(time.sleep, 0.5)
            try:
                if not connects:
                    with pytest.raises(LinkDown):
                        await th.open()
                    return
                await th.open()
                assert (await th.read())["T1"].celsius == pytest.approx(21.5)
            finally:
                await th.close()
    run(main())
