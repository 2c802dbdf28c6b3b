"""The Modbus driver against the simulated dispenser PLC over real TCP on loopback.

Farm time runs 100x faster than the wall (a 3 s auger run takes 30 ms); waits are on
conditions with a deadline, never on a fixed sleep.
"""
from __future__ import annotations

import asyncio
import time

import pytest
from pymodbus.client import AsyncModbusTcpClient

from controller.config import validate_section
from controller.errors import BadInput
from devices.clock import ScaledClock
from devices.dispenser.modbus_dispenser import (
    COMMAND_ADDR,
    COMMAND_REG,
    COMMAND_REGS,
    STATUS_ADDR,
    STATUS_FORMAT,
    Config,
    DeviceRefused,
    ModbusDispenser,
    to_registers,
)
from devices.dispenser.modbus_dispenser import START as START_CMD
from devices.errors import DeviceFault, DeviceTimeout, LinkDown, ProtocolError
from devices.sim.dispenser import SimDispenser, SimDispenserParams
from devices.sim.truth import TruthLog

SPEED = 100.0
NOISY = SimDispenserParams(rate_g_s=11.0, rate_noise=0.04, rate_drift=0.0, seed=4)


def config(port: int, timeout_s: float = 0.5, retries: int = 0) -> Config:
    return Config(kind="dispenser", driver="modbus", port=port, timeout_s=timeout_s, retries=retries)


def serve(body, *, params: SimDispenserParams = NOISY, at_food_box=None, timeout_s=0.5, retries=0):
    """Run ``body(sim, dispenser, clock)`` with a simulated PLC listening and the driver open."""
    async def main():
        clock = ScaledClock.starting(SPEED)
        sim = SimDispenser(params, clock, at_food_box=at_food_box)
        await sim.start()
        dispenser = ModbusDispenser("dispenser", config(sim.port, timeout_s, retries), clock)
        try:
            await dispenser.open()
            await body(sim, dispenser, clock)
        finally:
            await dispenser.close()
            await sim.stop()
    asyncio.run(main())


async def until(predicate, wall_s: float = 5.0, what: str = "condition"):
    deadline = time.monotonic() + wall_s
    while not (result := await predicate()):
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        await asyncio.sleep(0.002)
    return result


async def idle(dispenser):
    async def check():
        state = await dispenser.read()
        return state if not state.running else None
    return await until(check, what="the auger to stop")


def test_run_delivers_rate_times_time_and_counters_advance_once_with_the_tag():
    async def body(sim, dispenser, clock):
        before = await dispenser.read()
        assert (before.cycles, before.resolution_g, before.hopper_g) == (0, 0.1, 6000.0)
        await dispenser.run_auger(3.0, tag=41)
        # the PLC times the run itself: its counters advance with no one reading them
        async def counted():
            return sim.physics.cycles == 1
        await until(counted, what="the run to be counted by the device timer")
        state = await idle(dispenser)
        assert (state.cycles, state.last_tag, state.run_tag, state.jammed) == (1, 41, 0, False)
        assert abs(state.last_grams - 11.0 * 3.0) <= 4 * 0.04 * 11.0 * 3.0          # within noise
        assert abs(state.last_grams - sim.physical_total_g) <= state.resolution_g    # the load cell
        assert state.total_grams == state.last_grams
        assert state.hopper_g == pytest.approx(before.hopper_g - state.last_grams)
        for tag in (42, 43):
            await dispenser.run_auger(2.0, tag)
            state = await idle(dispenser)
        assert (state.cycles, state.last_tag) == (3, 43)
        assert state.total_grams == pytest.approx(sum(r.measured_g for r in sim.physics.runs))
        assert abs(state.total_grams - sim.physical_total_g) <= state.resolution_g
    serve(body)


def test_start_while_running_is_refused_and_stop_delivers_partially():
    async def body(sim, dispenser, clock):
        await dispenser.run_auger(300.0, tag=1)          # 3 s of wall time: surely still running
        with pytest.raises(DeviceFault) as exc:
            await dispenser.run_auger(5.0, tag=2)
        assert isinstance(exc.value, DeviceRefused) and exc.value.code == 6
        with pytest.raises(DeviceRefused):
            await dispenser.set_refill(True)
        state = await dispenser.read()
        assert state.running and state.run_tag == 1 and state.fate(2) == "not_started"
        await dispenser.stop()
        state = await dispenser.read()
        assert not state.running and (state.cycles, state.last_tag) == (1, 1)
        assert 0 < state.last_grams < 0.5 * 11.0 * 300.0
        assert abs(state.last_grams - sim.physical_total_g) <= state.resolution_g
    serve(body)


def test_a_resent_start_never_runs_twice():
    async def body(sim, dispenser, clock):
        await dispenser.run_auger(50.0, tag=7)
        await dispenser.run_auger(50.0, tag=7)           # e.g. resent after a lost reply: no error
        assert (await idle(dispenser)).cycles == 1
        await dispenser.run_auger(50.0, tag=7)           # after it finished, still no second run
        state = await dispenser.read()
        assert not state.running and state.cycles == 1 and len(sim.physics.runs) == 1
    serve(body)


def test_a_restarted_controller_reconciles_an_open_intent_from_the_counters():
    async def body(sim, first, clock):
        await first.run_auger(50.0, tag=9)               # intent 9 committed, auger started...
        await first.close()                              # ...and the controller dies
        second = ModbusDispenser("dispenser", config(sim.port), clock)
        async with second:
            state = await second.read()
            assert state.fate(9) == "running"
            await second.run_auger(50.0, tag=9)          # a naive retry does not dispense again
            state = await idle(second)
            assert state.fate(9) == "done" and state.cycles == 1
            assert abs(state.last_grams - sim.physics.runs[0].physical_g) <= state.resolution_g
            assert state.fate(10) == "not_started"
    serve(body)


def test_jam_is_latched_refuses_runs_and_clears():
    async def body(sim, dispenser, clock):
        sim.inject_jam(at_fraction=0.5)
        await dispenser.run_auger(4.0, tag=5)
        state = await idle(dispenser)
        assert state.jammed and (state.cycles, state.last_tag) == (1, 5)
        assert abs(state.last_grams - sim.physics.runs[0].physical_g) <= state.resolution_g
        assert abs(state.last_grams - 11.0 * 2.0) <= 4 * 0.04 * 11.0 * 2.0      # half a run, then stall
        assert sim.physics.runs[0].t_end - sim.physics.runs[0].t_start == pytest.approx(2.0)
        with pytest.raises(DeviceFault) as exc:
            await dispenser.run_auger(4.0, tag=6)
        assert exc.value.code == 4 and "jammed" in str(exc.value)
        assert (await dispenser.read()).jammed
        await dispenser.clear_fault()
        assert not (await dispenser.read()).jammed
        await dispenser.run_auger(4.0, tag=6)
        state = await idle(dispenser)
        assert (state.cycles, state.last_tag, state.jammed) == (2, 6, False)
    serve(body)


def test_a_start_resent_after_its_run_jammed_is_not_an_error():
    async def body(sim, dispenser, clock):
        sim.inject_jam(at_fraction=0.5)
        await dispenser.run_auger(4.0, tag=8)
        assert (await idle(dispenser)).jammed
        await dispenser.run_auger(4.0, tag=8)          # the reply was lost: the run did happen
        state = await dispenser.read()
        assert state.fate(8) == "done" and state.cycles == 1 and len(sim.physics.runs) == 1
        with pytest.raises(DeviceRefused) as exc:      # a new run is refused: still jammed
            await dispenser.run_auger(4.0, tag=9)
        assert exc.value.code == 4
    serve(body)


def test_any_refusal_of_a_start_the_device_already_ran_is_success():
    async def body(sim, dispenser, clock):
        await dispenser.run_auger(2.0, tag=3)
        await idle(dispenser)
        for code in (3, 4, 6):                         # whatever a PLC answers to the resend
            sim.inject_exception(code)
            await dispenser.run_auger(2.0, tag=3)
        sim.inject_exception(4)                        # but a refused new run is an error
        with pytest.raises(DeviceRefused) as exc:
            await dispenser.run_auger(2.0, tag=4)
        assert exc.value.code == 4
        assert (await dispenser.read()).cycles == 1
    serve(body)


def test_refill_only_at_the_food_box():
    arrived = [float("inf")]                  # farm time the carriage reaches the food box

    def at_box(t_from, t_to):                 # farm seconds of [t_from, t_to] at the box
        return max(0.0, t_to - max(t_from, arrived[0]))

    async def body(sim, dispenser, clock):
        await dispenser.run_auger(100.0, tag=1)
        await dispenser.stop()
        low = (await dispenser.read()).hopper_g
        await dispenser.set_refill(True)
        t_open = clock.now()
        async def two_farm_seconds_on():
            return clock.now() > t_open + 2.0
        await until(two_farm_seconds_on)
        state = await dispenser.read()
        assert state.refilling and state.hopper_g == low            # away from the box: nothing
        with pytest.raises(DeviceRefused) as exc:
            await dispenser.run_auger(1.0, tag=2)                   # no run with the gate open
        assert exc.value.code == 6
        arrived[0] = clock.now()
        async def full():
            return (await dispenser.read()).hopper_g >= 8000.0
        await until(full, what="the hopper to fill")
        await dispenser.set_refill(False)
        state = await dispenser.read()
        assert not state.refilling and state.hopper_g == 8000.0 and state.cycles == 1
    serve(body, at_food_box=at_box)


def test_unresponsive_device_times_out_then_recovers():
    async def body(sim, dispenser, clock):
        sim.set_unresponsive(True)
        with pytest.raises(DeviceTimeout):
            await dispenser.read()
        with pytest.raises(DeviceTimeout):
            await dispenser.run_auger(1.0, tag=3)
        assert sim.physics.cycles == 0 and not sim.physics.read().running   # nothing got through
        sim.set_unresponsive(False)
        assert (await dispenser.read()).cycles == 0
    serve(body, timeout_s=0.1)


def test_server_gone_is_link_down_and_the_driver_reconnects_when_it_returns():
    async def body(sim, dispenser, clock):
        await dispenser.run_auger(1.0, tag=1)
        await idle(dispenser)
        await sim.stop()
        for _ in range(2):
            with pytest.raises(LinkDown):
                await dispenser.read()
        await sim.start()                                           # same port, same physics
        state = await dispenser.read()
        assert (state.cycles, state.last_tag) == (1, 1)
    serve(body)


@pytest.mark.parametrize("connect_timeout_s, connects", [(None, True), (0.2, False)])
def test_a_connect_has_its_own_bound_not_a_reply_s(connect_timeout_s, connects):
    """The loop held as the handshake starts (a busy machine: the feeding rig's open failed so in a
    clean-clone CI run, 2026-12-05): a reply's 0.5 s bound read a live PLC as down; the connect
    waits ``connect_timeout_s`` (3 s unless set), and replies keep their own bound."""
    async def main():
        clock = ScaledClock.starting(SPEED)
        sim = SimDispenser(NOISY, clock)
        await sim.start()
        extra = {} if connect_timeout_s is None else {"connect_timeout_s": connect_timeout_s}
        dispenser = ModbusDispenser("dispenser", Config(kind="dispenser", driver="modbus", port=sim.port,
                                                        timeout_s=0.2, retries=0, **extra), clock)
        asyncio.get_running_loop().call_soon(time.sleep, 0.5)
        try:
            if not connects:
                with pytest.raises(LinkDown):
                    await dispenser.open()
                return
            await dispenser.open()
            assert (await dispenser.read()).cycles == 0
            sim.set_unresponsive(True)
            with pytest.raises(DeviceTimeout):   # the reply's bound, not the connect's (one test's wall)
                await asyncio.wait_for(dispenser.read(), 2.0)
        finally:
            await dispenser.close()
            await sim.stop()
    asyncio.run(main())


def test_dropped_connection_is_reconnected_and_a_pending_call_fails_at_once_when_the_device_goes():
    async def body(sim, dispenser, clock):
        for _ in range(3):
            sim.drop_connections()                                    # e.g. the PLC's idle timeout
            assert (await dispenser.read()).cycles == 0               # reconnected transparently
        sim.set_unresponsive(True)
        started = time.monotonic()
        pending = asyncio.create_task(dispenser.read())
        async def sent():
            return dispenser._in_flight
        await until(sent)
        await sim.stop()
        with pytest.raises(LinkDown):
            await pending
        assert time.monotonic() - started < 0.5 * 5.0                # not after the 5 s timeout
        sim.set_unresponsive(False)
        await sim.start()
        assert (await dispenser.read()).cycles == 0
    serve(body, timeout_s=5.0)


def test_exception_responses_are_device_faults_with_the_code():
    async def body(sim, dispenser, clock):
        sim.inject_exception(2)
        with pytest.raises(DeviceRefused) as exc:
            await dispenser.read()
        assert exc.value.code == 2 and "0x02" in str(exc.value)
        assert (await dispenser.read()).cycles == 0
        raw = AsyncModbusTcpClient("127.0.0.1", port=sim.port, timeout=1, retries=0, reconnect_delay=0)
        await raw.connect()
        try:
            assert (await raw.write_register(STATUS_ADDR, 1, device_id=1)).exception_code == 2
            assert (await raw.read_holding_registers(150, count=1, device_id=1)).exception_code == 2
            assert (await raw.write_register(COMMAND_ADDR + 3, 99, device_id=1)).exception_code == 3
            assert (await raw.write_registers(COMMAND_ADDR, [0, 0, 5, 1], device_id=1)).exception_code == 3
        finally:
            raw.close()
    serve(body)


def test_thread_served_sim_open_failure_and_close_twice():
    clock = ScaledClock.starting(SPEED)
    sim = SimDispenser(NOISY, clock).start_thread()

    async def main():
        dispenser = ModbusDispenser("dispenser", config(sim.port), clock)
        await dispenser.open()
        await dispenser.run_auger(2.0, tag=1)
        state = await idle(dispenser)
        await dispenser.close()
        await dispenser.close()
        with pytest.raises(LinkDown):
            await dispenser.read()
        return state

    try:
        state = asyncio.run(main())
    finally:
        sim.stop_thread()
    assert state.cycles == 1 and abs(state.last_grams - sim.physical_total_g) <= 0.1

    async def nobody_there():
        dispenser = ModbusDispenser("dispenser", config(sim.port), clock)
        with pytest.raises(LinkDown):
            await dispenser.open()
        with pytest.raises(LinkDown):
            await dispenser.read()
        await dispenser.close()
    asyncio.run(nobody_there())


def test_config_errors_name_the_field():
    good = {"kind": "dispenser", "driver": "modbus", "host": "10.0.0.5", "port": 502}
    assert validate_section(Config, good, "farm.toml", "devices.dispenser").timeout_s == 1.0
    for bad, field in [({"timeout_s": 0}, "timeout_s"), ({"port": 70000}, "port"), ({"unti": 1}, "unti")]:
        with pytest.raises(BadInput) as exc:
            validate_section(Config, {**good, **bad}, "farm.toml", "devices.dispenser")
        assert str(exc.value).startswith(f"farm.toml: devices.dispenser.{field}:")


def test_estop_latch_over_its_own_connection_refuses_start_and_gate_until_reset():
    async def body(sim, dispenser, clock):
        await dispenser.run_auger(300.0, tag=1)
        state = await asyncio.to_thread(dispenser.trip_estop)     # the lane's thread, not the loop
        assert state.estop and not state.running and not state.refilling
        assert sim.physics.estop_latched and (state.cycles, state.last_tag) == (1, 1)
        # a START after the e-stop is refused by the device itself, over the main connection
        with pytest.raises(DeviceRefused) as exc:
            await dispenser.run_auger(5.0, tag=2)
        assert exc.value.code == 4 and "e-stop" in str(exc.value)
        with pytest.raises(DeviceRefused) as exc:
            await dispenser.set_refill(True)
        assert exc.value.code == 4
        await dispenser.clear_fault()                              # not a reset
        assert (await dispenser.read()).estop and len(sim.physics.runs) == 1
        assert (await asyncio.to_thread(dispenser.trip_estop)).estop   # twice is fine
        await dispenser.reset_estop()
        assert not (await dispenser.read()).estop
        await dispenser.run_auger(5.0, tag=2)
        assert (await idle(dispenser)).last_tag == 2
    serve(body)


def test_estop_lane_reconnects_after_the_plc_dropped_it_and_fails_fast_when_it_is_gone():
    async def body(sim, dispenser, clock):
        sim.drop_connections()                                     # PLCs close idle connections
        assert (await asyncio.to_thread(dispenser.trip_estop)).estop
        await dispenser.reset_estop()
        sim.set_unresponsive(True)
        started = time.monotonic()
        with pytest.raises(DeviceTimeout):
            await asyncio.to_thread(dispenser.trip_estop)
        assert time.monotonic() - started < 2.0
        sim.set_unresponsive(False)
        assert (await asyncio.to_thread(dispenser.trip_estop)).estop
        await sim.stop()
        with pytest.raises(LinkDown):
            await asyncio.to_thread(dispenser.trip_estop)
        await dispenser.close()
        with pytest.raises(LinkDown):                              # closed: nothing to trip
            await asyncio.to_thread(dispenser.trip_estop)
    serve(body)


def _lose_the_reply_to_start(sim, *, restart: bool):
    """The PLC's answer to the next START never arrives: the connection drops under it, after the
    PLC ran the START and then lost power (``restart``), or before it read the request at all."""
    command = sim._command

    def on_command(start, address, registers, values):
        if address + len(values) > COMMAND_REG and values[-1] == START_CMD:
            sim._command = command
            if not restart:
                sim._drop()
                return None
            answer = command(start, address, registers, values)
            sim.power_cycle()                 # counters reset, connections dropped: no reply
            return answer
        return command(start, address, registers, values)
    sim._command = on_command


def _starts(truth, tag: int) -> int:
    return sum(r["kind"] == "auger_start" and r["tag"] == tag for r in truth.records)


def test_a_start_is_not_resent_to_a_plc_that_restarted_under_it():
    """A power cut between the PLC taking a START and its reply: a resend on the new connection
    would find a PLC that forgot the tag and run the portion twice. The driver looks first."""
    async def body(sim, dispenser, clock):
        sim.physics._truth = truth
        await dispenser.run_auger(0.5, 1)
        await until(lambda: idle(dispenser), what="first run done")
        await dispenser.read()                                     # the counters the controller saw
        _lose_the_reply_to_start(sim, restart=True)
        with pytest.raises(DeviceFault, match="restarted"):
            await dispenser.run_auger(3.0, 2)
        assert _starts(truth, 2) == 1                              # the cut run, and no second one
        assert not (await dispenser.read()).running
    truth = TruthLog(None)
    serve(body)


def test_a_start_whose_request_was_lost_with_its_connection_is_sent_again_and_runs_once():
    async def body(sim, dispenser, clock):
        sim.physics._truth = truth
        await dispenser.read()
        _lose_the_reply_to_start(sim, restart=False)
        await dispenser.run_auger(0.5, 7)
        await until(lambda: idle(dispenser), what="run done")
        state = await dispenser.read()
        assert state.last_tag == 7 and state.cycles == 1 and _starts(truth, 7) == 1
    truth = TruthLog(None)
    serve(body)


@pytest.mark.parametrize("res_mg", [0, 10, 100])
def test_the_load_cell_s_resolution_is_the_plc_s_and_zero_is_refused(res_mg):
    """A PLC's own status block (not the simulator's): RES_MG 0 read every gram as 0 — a dispense
    booked as 0 g, a full hopper read empty and the gate held open to refill it."""
    from pymodbus.server import ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    async def main():
        fields = to_registers(STATUS_FORMAT, 0, 0, 80_000, 3, 2, 200, 1_000, res_mg)
        plc = ModbusTcpServer(SimDevice(1, simdata=[
            SimData(STATUS_ADDR, values=fields, datatype=DataType.REGISTERS),
            SimData(COMMAND_ADDR, count=COMMAND_REGS, datatype=DataType.REGISTERS)]), address=("127.0.0.1", 0))
        await plc.serve_forever(background=True)
        port = plc.transport.sockets[0].getsockname()[1]
        dispenser = ModbusDispenser("plc", Config(kind="dispenser", driver="modbus", port=port), ScaledClock.real())
        await dispenser.open()
        try:
            if res_mg == 0:
                with pytest.raises(ProtocolError, match="RES_MG is 0 mg per count"):
                    await dispenser.read()
            else:
                state = await dispenser.read()
                assert (state.hopper_g, state.last_grams, state.resolution_g) == pytest.approx(
                    (80_000 * res_mg / 1000, 200 * res_mg / 1000, res_mg / 1000))
        finally:
            await dispenser.close()
            await plc.shutdown()
    asyncio.run(asyncio.wait_for(main(), 30))
