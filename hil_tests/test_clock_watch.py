"""The clock watch judges whether the clock ran fast through a farm instant (a fish episode's start)
by both the segment seen in force then and its next sample, each of which alone misreads: at 600x
the next sample is up to 6 farm s later, after a demand turned down a second after the start has
let the clock speed up; and a segment written in the last 10 ms of wall before the start (the
simulator's lookahead moved to it) is never seen, so the one seen is an older, faster one."""
from __future__ import annotations

from devices.elastic_clock import ElasticClock, create
from hil_tests.clock_watch import ClockWatch
from tests.devices.test_elastic_clock import Wall  # a wall clock a test moves by hand

SLOW, FAST, START = 600.0, 60_000.0, 1_780_000_000.0


def farm(tmp_path):
    wall = Wall()
    create(tmp_path / "clock", slow=SLOW, fast=FAST, farm_start=START, wall_time=wall, lease_s=0.0)  # no renewals
    sim, ctl = (ElasticClock(tmp_path / "clock", wall_time=wall, alive=lambda pid: True) for _ in range(2))
    sim.claim("sim")
    ctl.claim("controller")
    return wall, sim, ctl, ClockWatch(ctl)


def go_to(wall, clock, farm_t):
    """Move the wall to where the clock reads ``farm_t`` (within the current segment)."""
    seg = clock.segment()
    lo, hi = wall.t, wall.t + 10.0
    for _ in range(100):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if seg.farm_at(mid) < farm_t else (lo, mid)
    wall.t = hi


def test_an_episode_started_slow_reads_slow_though_the_clock_sped_up_a_second_later(tmp_path):
    wall, sim, ctl, watch = farm(tmp_path)
    start = START + 20_000.0
    ctl.idle_until(START + 1e6, why="next survey")
    sim.idle_until(start - 5.0, why="next episode")          # the simulator's lead before the start
    watch.sample(wall.t)
    go_to(wall, ctl, start - 3.0)                             # slow by itself at the limit
    watch.sample(wall.t)
    sim.busy(why="fish asking")                               # the episode starts
    go_to(wall, ctl, start + 1.2)
    sim.idle_until(start + 7_200.0, why="unheeded fish")      # a demand heard, turned down: nobody busy
    go_to(wall, ctl, start + 400.0)
    watch.sample(wall.t)                                      # the next look: already fast
    assert watch.speed_after(start) == FAST                   # the next sample alone misreads
    assert watch.speed_at(start) == SLOW
    assert watch.speed_at(start - 100.0) == FAST and watch.speed_at(start + 300.0) == FAST
    assert not watch.ran_fast_at(start)


def test_an_episode_whose_slowing_segment_went_unseen_reads_slow(tmp_path):
    wall, sim, ctl, watch = farm(tmp_path)
    start = START + 20_000.0
    ctl.idle_until(START + 1e6)
    sim.idle_until(start + 3_000.0)                           # the lookahead as it stood
    watch.sample(wall.t)
    go_to(wall, ctl, start - 200.0)
    sim.idle_until(start - 5.0)                               # moved to the start: no look sees this
    go_to(wall, ctl, start + 0.5)                             # the simulator's next look after the start
    sim.busy(why="fish asking")                               # the episode, served: slow for a while
    go_to(wall, ctl, start + 4.0)
    watch.sample(wall.t)
    assert watch.speed_at(start) == FAST                      # the segment seen alone misreads
    assert watch.speed_after(start) == SLOW
    assert not watch.ran_fast_at(start)


def test_an_episode_the_clock_ran_through_fast_reads_fast(tmp_path):
    wall, sim, ctl, watch = farm(tmp_path)
    start = START + 20_000.0
    ctl.idle_until(START + 1e6)
    sim.idle_until(start + 600.0)                             # a lookahead that missed the start
    watch.sample(wall.t)
    go_to(wall, ctl, start + 300.0)
    watch.sample(wall.t)
    assert watch.speed_at(start) == FAST
    assert watch.ran_fast_at(start)
    assert watch.speed_at(START - 1.0) is None                # before anything was seen
