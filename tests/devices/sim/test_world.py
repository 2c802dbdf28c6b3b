"""The simulated world links the devices' physics: food falls where the carriage was when it fell,
and the hopper fills for the time the carriage stood at the food box. Farm time is a ManualClock,
and nothing looks at the dispenser between the start of a run and its end, as at 1440x."""
from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from controller.config import Config, FeedingConfig, TankConfig
from devices.clock import ManualClock
from devices.errors import BadInput
from devices.rail.can_frames import Command, Op, Reason
from devices.sim.dispenser import DispenserPhysics, SimDispenserParams
from devices.sim.truth import TruthLog
from devices.sim.world import FOOD_BOX_M, TANK_MOUTH_M, SimFarm, check_sim

RATE, ACCEL, VMAX = 10.0, 0.5, 1.0
TANKS = {"A": 3.0, "B": 4.0}


def farm_config() -> Config:
    tanks = [TankConfig(id=tid, stock=1000, mean_weight_g=50, position_m=pos, sensors=[f"{tid}-a"])
             for tid, pos in TANKS.items()]
    return Config(tanks=tanks, feeding=FeedingConfig(food_box_m=0.0), path="<test>",
                  devices={name: {"kind": name, "driver": "sim"} for name in ("rail", "dispenser", "contacts")},
                  sim={"rail": {"max_speed_m_s": VMAX, "accel_m_s2": ACCEL},
                       "dispenser": {"rate_g_s": RATE, "rate_noise": 0.0, "rate_drift": 0.0}})


def command(farm, op: Op, target: float = 0.0, seq: int = 1) -> None:
    assert farm.motor.handle(Command(op, seq, target, 0.0)) is Reason.ACCEPTED


def in_world(body):
    """Start the simulated farm (rail on an slcan pty, dispenser on Modbus TCP, contact hub) and
    run ``body(farm, clock)``; physics is driven directly, the servers only have to be up."""
    async def main():
        clock, truth = ManualClock(), TruthLog(None)
        farm = SimFarm(farm_config(), clock, truth)
        await farm.start()
        try:
            return body(farm, clock)
        finally:
            await farm.stop()
    return asyncio.run(main())


def seconds_where(motor, t0: float, t1: float, inside) -> float:
    """Farm seconds of [t0, t1] for which ``inside(position)`` holds, sampled finely (the truth)."""
    t = np.linspace(t0, t1, 200_001)
    p = np.array([motor.position(x) for x in t])
    return float(np.mean(inside(p)) * (t1 - t0))


def test_food_is_credited_where_it_fell_while_the_carriage_moved_between_looks():
    def body(farm, clock):
        command(farm, Op.HOME, seq=1)
        command(farm, Op.MOVE, TANKS["A"], seq=2)
        clock.advance(60.0)
        assert farm.motor.position() == TANKS["A"]
        physics = farm.dispenser.physics
        t0 = clock.now()
        physics.start_run(10.0, tag=1)
        clock.advance(5.0)
        command(farm, Op.MOVE, TANKS["B"], seq=3)          # halfway through, off to tank B
        clock.advance(5.0)
        physics.update()                                    # the first look since the start
        return farm, t0

    farm, t0 = in_world(body)
    motor, truth = farm.motor, farm.truth.records
    expect = {tid: RATE * seconds_where(motor, t0, t0 + 10.0, lambda p, x=pos: np.abs(p - x) <= TANK_MOUTH_M)
              for tid, pos in TANKS.items()}
    expect[None] = RATE * 10.0 - sum(expect.values())
    assert expect["A"] > 55.0 and expect["B"] > 25.0 and expect[None] > 5.0   # all three happen
    delivered = {r["tank"]: r["grams"] for r in truth if r["kind"] == "delivered"}
    assert len([r for r in truth if r["kind"] == "delivered"]) == 3           # one record a place
    assert delivered == pytest.approx(expect, abs=0.005)                     # the sampling's error
    assert farm.spilled_g == pytest.approx(expect[None], abs=0.005)
    fed = {r["tank"]: r["grams"] for r in truth if r["kind"] == "fed"}
    assert fed == pytest.approx({"A": delivered["A"], "B": delivered["B"]}, abs=1e-3)
    stamps = {r["tank"]: r["t"] for r in truth if r["kind"] == "delivered"}
    assert t0 + 5.0 < stamps["A"] < stamps[None] < stamps["B"] == pytest.approx(t0 + 10.0)
    assert sum(delivered.values()) == pytest.approx(farm.dispenser.physical_total_g, abs=1e-3)


def test_hopper_fills_only_for_the_time_at_the_food_box_between_looks():
    def body(farm, clock):
        command(farm, Op.HOME, seq=1)
        clock.advance(1.0)
        physics = farm.dispenser.physics
        before = physics.hopper_g
        physics.set_gate(True)
        t0 = clock.now()
        clock.advance(2.0)
        command(farm, Op.MOVE, TANKS["A"], seq=2)            # leaves the box with the gate open
        clock.advance(10.0)
        return farm, t0, physics.hopper_g - before        # the first look since the gate opened

    farm, t0, filled = in_world(body)
    refill = SimDispenserParams().refill_rate_g_s
    leave_s = math.sqrt(2 * FOOD_BOX_M / ACCEL)             # accelerating from rest to the box's edge
    assert filled == pytest.approx(refill * (2.0 + leave_s), rel=1e-7)     # farm time: 0.24 µs ulps
    at_box = seconds_where(farm.motor, t0, t0 + 12.0, lambda p: np.abs(p) <= FOOD_BOX_M)
    assert filled == pytest.approx(refill * at_box, rel=1e-3)


def test_the_old_point_callbacks_still_work():
    """``deliver(grams, t)`` and ``at_food_box(t)``: everything at the end, judged at both ends."""
    clock, got = ManualClock(), []
    physics = DispenserPhysics(SimDispenserParams(rate_g_s=RATE, rate_noise=0.0, rate_drift=0.0), clock,
                               deliver=lambda grams, t: got.append((grams, t)), at_food_box=lambda t: True)
    physics.start_run(3.0, tag=1)
    clock.advance(5.0)
    physics.update()
    assert got == [(pytest.approx(RATE * 3.0), pytest.approx(physics.runs[0].t_end))]
    physics.set_gate(True)
    clock.advance(1.0)
    assert physics.hopper_g == pytest.approx(6000.0 - RATE * 3.0 + 400.0)


def _rail_farm(positions: dict[str, float], food_box_m: float = 0.0, rail: dict | None = None,
               driver: str = "sim") -> Config:
    tanks = [TankConfig(id=tid, stock=1000, mean_weight_g=50, position_m=pos, sensors=[f"{tid}-a"])
             for tid, pos in positions.items()]
    return Config(tanks=tanks, feeding=FeedingConfig(food_box_m=food_box_m), path="<test>",
                  devices={"rail": {"kind": "rail", "driver": driver}}, sim={"rail": rail or {}})


@pytest.mark.parametrize("positions, box, rail, key", [
    ({"A": 3.0, "B": 22.5}, 0.0, {}, "tanks.1.position_m: tank 'B' at 22.5 m is beyond the simulated rail's end"),
    ({"A": 3.0, "B": 9.0}, 8.5, {"rail_length_m": 8.0},
     "tanks.1.position_m: tank 'B' at 9 m is beyond the simulated rail's end (sim.rail.rail_length_m = 8 m)"),
    ({"A": 3.0}, 12.0, {"rail_length_m": 10.0}, "feeding.food_box_m: the food box at 12 m is beyond"),
    ({"A": 5.0, "B": 3.0, "C": 5.0 - 2 * TANK_MOUTH_M + 0.01}, 0.0, {},
     "tanks.2.position_m: tank 'C' is 0.59 m from tank 'A': the simulated tanks' mouths (0.3 m each side) would"),
])
def test_tanks_and_the_food_box_off_the_simulated_rail_or_overlapping_are_refused(positions, box, rail, key):
    """A tank beyond the rail's soft limit was a robot driving into the limit for good; two tanks
    whose chute mouths overlap had one's food credited to the other."""
    with pytest.raises(BadInput) as exc:
        check_sim(_rail_farm(positions, box, rail))
    assert str(exc.value).startswith("<test>: ") and key in str(exc.value)


@pytest.mark.parametrize("positions, box, rail", [
    ({"A": 3.0, "B": 22.0}, 22.0, {}),                                  # at the end itself
    ({"A": 3.0, "B": 3.0 + 2 * TANK_MOUTH_M}, 0.0, {"rail_length_m": 4.0}),   # mouths touching
])
def test_tanks_on_the_rail_and_apart_pass(positions, box, rail):
    check_sim(_rail_farm(positions, box, rail))


def test_a_real_rail_is_not_held_to_the_simulated_one():
    check_sim(_rail_farm({"A": 3.0, "B": 40.0}, driver="can"))
