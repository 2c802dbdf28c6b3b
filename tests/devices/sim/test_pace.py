"""The simulator's word to an elastic clock: busy while fish ask, else idle until the next episode."""
from __future__ import annotations

from dataclasses import dataclass

from devices.elastic_clock import BUSY, IDLE, ElasticClock, create
from devices.sim.pace import ATTENTION_S, LEAD_S, declare

START = 1_780_000_000.0


@dataclass
class Tank:
    asking: bool
    start: float
    heeded_t: float = START
    again: float = START + 10_000.0
    id: str = "T1"

    def next_episode(self, now: float) -> float:
        return now if self.asking else self.start

    def unheeded_until(self) -> float:
        return self.again


def clock(tmp_path):
    create(tmp_path / "clock", slow=100.0, fast=10_000.0, farm_start=START, wall_time=lambda: 0.0)
    c = ElasticClock(tmp_path / "clock", wall_time=lambda: 0.0, alive=lambda pid: True)
    c.claim("sim")
    return c


def mine(c):
    return c.slots()[c.slot]


def test_idle_until_the_earliest_next_episode_less_the_lead(tmp_path):
    c = clock(tmp_path)
    declare(c, [Tank(False, START + 5_000.0), Tank(False, START + 3_000.0)])
    assert (mine(c).kind, mine(c).value) == (IDLE, START + 3_000.0 - LEAD_S)


def test_busy_while_any_tank_asks_and_with_no_tanks(tmp_path):
    c = clock(tmp_path)
    declare(c, [Tank(False, START + 5_000.0), Tank(True, 0.0)])
    assert (mine(c).kind, mine(c).why) == (BUSY, "fish asking")
    declare(c, [])
    assert mine(c).kind == BUSY


def test_fish_asking_unfed_past_the_attention_span_wait_for_their_next_start(tmp_path):
    c = clock(tmp_path)                        # its wall stands still: now() is START
    heeded = Tank(True, 0.0, heeded_t=START - ATTENTION_S + 1.0)
    declare(c, [Tank(False, START + 5_000.0), heeded])
    assert mine(c).kind == BUSY                # within the span: a demand may come
    ignored = Tank(True, 0.0, heeded_t=START - ATTENTION_S - 1.0, again=START + 2_000.0)
    declare(c, [Tank(False, START + 5_000.0), ignored])
    assert (mine(c).kind, mine(c).value, mine(c).why) == (IDLE, START + 2_000.0 - LEAD_S, "unheeded fish")


def test_fish_the_controller_has_heard_since_their_start_or_meal_hold_the_clock_no_longer(tmp_path):
    c = clock(tmp_path)                        # now() is START
    asking = Tank(True, 0.0, heeded_t=START - 30.0, again=START + 2_000.0)
    declare(c, [asking], heard=lambda tank: START - 40.0)    # heard before their last meal: not this ask
    assert (mine(c).kind, mine(c).why) == (BUSY, "fish asking")
    declare(c, [asking], heard=lambda tank: START - 10.0)    # heard since: the controller holds it if it acts
    assert (mine(c).kind, mine(c).value) == (IDLE, START + 2_000.0 - LEAD_S)


def test_a_heard_tank_does_not_release_another_that_still_asks_unheard(tmp_path):
    c = clock(tmp_path)
    heard_at = {"A": START - 5.0}
    a = Tank(True, 0.0, heeded_t=START - 20.0, id="A")
    b = Tank(True, 0.0, heeded_t=START - 20.0, id="B")
    declare(c, [a, b], heard=lambda tank: heard_at.get(tank, float("-inf")))
    assert mine(c).kind == BUSY
    heard_at["B"] = START - 1.0
    declare(c, [a, b], heard=lambda tank: heard_at.get(tank, float("-inf")))
    assert mine(c).kind == IDLE
