"""The elastic clock (devices/elastic_clock.py) on a fake wall: continuity, monotony, the segment's
own slow-down at the lookahead limit, sleepers across speed changes, slots, readers in other processes
(on files without a lease: words hold until changed), and the leases of the words (``leased``)."""
from __future__ import annotations

import asyncio
import math
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import time

import pytest

from devices.clock_file import CRAWL, LEASE_S, process_alive
from devices.clock_reading import STALE_S
from devices.elastic_clock import FAST_NAP_S, SEEN_EVERY_S, SLICE_S, ElasticClock, create

SLOW, FAST, START = 100.0, 10_000.0, 1_780_000_000.0


class Wall:
    """A wall clock a test moves by hand."""

    def __init__(self, t: float = 5_000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def wall():
    return Wall()


@pytest.fixture
def path(tmp_path, wall):
    p = tmp_path / "clock"
    create(p, slow=SLOW, fast=FAST, farm_start=START, wall_time=wall, lease_s=0.0)
    return p


def handle(path, wall, name=None, alive=lambda pid: True, **kw):
    c = ElasticClock(path, wall_time=wall, alive=alive, **kw)
    if name:
        c.claim(name)
    return c


def test_a_new_clock_runs_at_the_slow_speed_from_its_start(path, wall):
    c = handle(path, wall)
    assert c.now() == START
    wall.t += 2.0
    assert c.now() == pytest.approx(START + 2.0 * SLOW)
    assert c.speed == SLOW


def test_everyone_idle_runs_fast_then_slows_by_itself_at_the_earliest_limit(path, wall):
    sim, ctl = handle(path, wall, "sim"), handle(path, wall, "controller")
    sim.idle_until(START + 50_000.0)
    assert sim.speed == SLOW                   # the controller has not spoken: still busy
    ctl.idle_until(START + 20_000.0)
    assert ctl.speed == FAST
    wall.t += 1.0                              # 10 000 farm s at FAST
    assert ctl.now() == pytest.approx(START + 10_000.0)
    wall.t += 1.5                              # 1 s more reaches the limit, the 0.5 s after it are slow
    assert ctl.now() == pytest.approx(START + 20_000.0 + 0.5 * SLOW)
    assert ctl.speed == SLOW


def test_speed_changes_keep_farm_time_continuous_and_monotonic(path, wall):
    sim, ctl = handle(path, wall, "sim"), handle(path, wall, "controller")
    seen = []
    for step in range(40):                     # busy and idle alternating at odd instants
        wall.t += 0.013 * (1 + step % 5)
        before = ctl.now()
        if step % 3 == 0:
            sim.busy()
        elif step % 3 == 1:
            sim.idle_until(before + 1_000.0 * (step % 7))
        else:
            ctl.idle_until(before + 5_000.0)
        after = ctl.now()
        assert after == pytest.approx(before, abs=1e-6)   # no jump when the segment is re-drawn
        seen.append(after)
    assert seen == sorted(seen)


def test_a_busy_process_caps_the_speed_at_its_word(path, wall):
    sim, ctl = handle(path, wall, "sim"), handle(path, wall, "controller")
    sim.idle_until(START + 1e6)
    ctl.busy(max_speed=40.0)
    assert ctl.speed == 40.0
    ctl.busy(max_speed=1e9)                    # never above the file's fast speed
    assert ctl.speed == FAST


def test_awaited_and_dead_slots_hold_the_clock_slow(tmp_path, wall):
    p = tmp_path / "clock"
    create(p, slow=SLOW, fast=FAST, farm_start=START, awaited=("sim", "controller"), wall_time=wall)
    dead: set[int] = set()
    sim = handle(p, wall, "sim", alive=lambda pid: pid not in dead)
    sim.idle_until(START + 1e6)
    assert sim.speed == SLOW                   # the controller is awaited
    ctl = handle(p, wall, "controller", alive=lambda pid: pid not in dead)
    ctl.idle_until(START + 1e6)
    assert sim.speed == FAST
    dead.add(ctl.slots()[1].pid)               # its process is gone: its word no longer holds
    assert sim.govern().speed == SLOW
    dead.clear()                               # (one pid for both handles here)
    ctl.busy()
    ctl.release()
    assert sim.govern().speed == FAST          # a process that leaves on purpose holds nothing back


@pytest.fixture
def leased(tmp_path, wall):
    """A clock file with the lease every farm's file has (LEASE_S of wall a word)."""
    p = tmp_path / "leased"
    create(p, slow=SLOW, fast=FAST, farm_start=START, wall_time=wall)
    return p


def _run(wall, seconds: float, words=(), step: float = 0.005) -> None:
    """Move the wall ``seconds`` on in ``step``s, each word given again after each (as the pacers do)."""
    for _ in range(round(seconds / step)):
        wall.t += step
        for word in words:
            word()


def test_words_given_again_hold_the_speed_they_ask_for(leased, wall):
    sim, ctl = handle(leased, wall, "sim"), handle(leased, wall, "controller")
    words = [lambda: sim.idle_until(START + 1e9), lambda: ctl.idle_until(START + 1e9)]
    for word in words:
        word()
    start = ctl.now()
    _run(wall, 1.0, words)
    assert ctl.now() - start == pytest.approx(FAST * 1.0, abs=1e-3)
    busy = [lambda: sim.busy(), lambda: ctl.idle_until(START + 1e9)]
    for word in busy:
        word()
    before = ctl.now()
    _run(wall, 1.0, busy)
    assert ctl.now() - before == pytest.approx(SLOW * 1.0, abs=1e-3)


def test_a_process_that_stops_giving_its_word_slows_the_farm_whoever_else_does(leased, wall):
    """Descheduled on a loaded machine, the controller read no contact for 0.9 s while the farm ran
    9 hours fast; the episode after it was heard minutes late. Now its idle word lapses: fast for
    the lease, though the simulator goes on giving its own; then a crawl (slow at the lapse, for at
    most the simulator's next word: it re-draws the segment, and finds the controller's lapsed)."""
    sim, ctl = handle(leased, wall, "sim"), handle(leased, wall, "controller")
    sim.idle_until(START + 1e9)
    ctl.idle_until(START + 1e9)
    start = ctl.now()
    _run(wall, 1.0, [lambda: sim.idle_until(START + 1e9)])         # the controller says nothing
    lease = ctl.lease_s
    assert lease == pytest.approx(LEASE_S)
    assert ctl.now() - start == pytest.approx(FAST * lease + SLOW * CRAWL * (1.0 - lease), abs=SLOW * 0.01)
    assert ctl.speed == SLOW * CRAWL
    ctl.idle_until(START + 1e9)                                    # it runs again: fast at once
    assert ctl.speed == FAST


def test_a_busy_word_not_given_again_crawls_and_one_given_again_does_not(leased, wall):
    sim, ctl = handle(leased, wall, "sim"), handle(leased, wall, "controller")
    sim.busy()
    ctl.busy(max_speed=SLOW / 2)
    start = ctl.now()
    wall.t += 1.0                               # nobody gives a word: the lease, then a crawl
    lease = ctl.lease_s
    assert ctl.now() - start == pytest.approx(SLOW / 2 * (lease + CRAWL * (1.0 - lease)), abs=1e-3)
    sim.busy()
    ctl.busy(max_speed=SLOW / 2)                # both again: the slower word's speed
    assert ctl.speed == SLOW / 2
    assert ctl.segment().after == pytest.approx(SLOW / 2 * CRAWL)


def test_busy_at_the_fast_speed_with_nobody_idle_holds_it_for_the_lease(leased, wall):
    sim, ctl = handle(leased, wall, "sim"), handle(leased, wall, "controller")
    sim.busy(max_speed=1e9)
    ctl.busy(max_speed=1e9)
    seg = ctl.segment()
    assert seg.speed == FAST and seg.limit == pytest.approx(seg.farm0 + FAST * LEASE_S)
    assert seg.after == SLOW * CRAWL            # lapsed: a crawl, as every lapse is


def test_a_dead_process_holds_the_farm_slow_not_at_a_crawl(leased, wall):
    dead: set[int] = set()
    sim = handle(leased, wall, "sim", alive=lambda pid: pid not in dead)
    ctl = handle(leased, wall, "controller", alive=lambda pid: pid not in dead)
    sim.idle_until(START + 1e9)
    ctl.idle_until(START + 1e9)
    dead.add(ctl.slots()[1].pid)                # (one pid for both handles here: the sim's word too)
    wall.t += 1.0
    seg = sim.govern()
    assert (seg.speed, seg.limit) == (SLOW, math.inf)


def test_every_process_stopped_crawls_as_one_stopped_does(leased, wall):
    """With one of two stopped, the other's next word drew the crawl; with both stopped nobody was
    left to draw it and the farm ran on slow, 10x faster (an outside tester)."""
    sim, ctl = handle(leased, wall, "sim"), handle(leased, wall, "controller")
    sim.idle_until(START + 1e9)
    ctl.idle_until(START + 1e9)
    start = ctl.now()
    wall.t += 0.5                              # neither says a word
    assert ctl.now() - start == pytest.approx(FAST * LEASE_S + SLOW * CRAWL * (0.5 - LEASE_S), abs=1e-3)


def test_a_reader_draws_a_segment_every_holder_left_again(leased, wall):
    """Every holder SIGKILLed, the last segment drawn (a crawl after a lease) stood for good though
    README gives a dead holder's word the slow speed (an outside tester). A segment nobody drew
    again for STALE_S is drawn again by whoever reads it: dead holders slow, stopped ones a crawl."""
    dead: set[int] = set()
    sim = handle(leased, wall, "sim", alive=lambda pid: pid not in dead)
    ctl = handle(leased, wall, "controller", alive=lambda pid: pid not in dead)
    sim.busy()
    ctl.busy()
    reader = handle(leased, wall, alive=lambda pid: pid not in dead)
    wall.t += 0.5
    assert reader.speed == SLOW * CRAWL        # stopped, or dead: the segment cannot tell yet
    wall.t += STALE_S
    assert reader.speed == SLOW * CRAWL        # drawn again: alive and silent, a crawl
    dead.add(ctl.slots()[0].pid)               # (one pid for every handle here)
    wall.t += STALE_S + 0.01
    seg = reader.segment()
    assert (seg.speed, seg.limit) == (SLOW, math.inf)
    before = reader.now()
    wall.t += 1.0
    assert reader.now() - before == pytest.approx(SLOW * 1.0, abs=1e-6)


def test_a_zombie_is_no_live_process(tmp_path):
    """Killed and not yet reaped by its parent, a holder counted as alive: its lapsed word a crawl
    and --show not marking it dead."""
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        assert process_alive(child.pid) and process_alive(os.getpid())
        os.kill(child.pid, signal.SIGKILL)
        deadline = time.monotonic() + 10
        while process_alive(child.pid) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not process_alive(child.pid)
        assert child.poll() == -signal.SIGKILL   # it was a zombie until now
    finally:
        child.kill()
        child.wait()


def test_claiming_again_by_name_takes_the_same_slot(path, wall):
    a = handle(path, wall, "controller")
    b = handle(path, wall, "controller")
    assert a.slot == b.slot
    assert [s.name for s in a.slots()].count("controller") == 1


def test_a_sleeper_wakes_at_its_farm_time_when_the_speed_rises_mid_sleep(path, wall):
    sim, ctl = handle(path, wall, "sim"), handle(path, wall, "controller")
    sim.busy()
    ctl.idle_until(START + 1e9)
    naps = []

    def pause(s):
        naps.append(s)
        wall.t += s
        if len(naps) == 3:                     # another process goes idle: the speed rises x100
            sim.idle_until(START + 1e9)

    sleeper = handle(path, wall, pause=pause)
    target = sleeper.now() + 5_000.0           # 50 wall s at SLOW, 0.5 at FAST
    sleeper.sleep(5_000.0)
    woke = sleeper.now()
    assert woke >= target
    assert woke - target <= SLICE_S * FAST + 1e-6
    assert sum(naps) < 1.0                     # it did not sleep its slow-speed 50 s


def test_a_sleeper_inside_the_fast_part_naps_once_and_one_slowed_under_it_looks_again(path, wall):
    sim, ctl = handle(path, wall, "sim"), handle(path, wall, "controller")
    sim.idle_until(START + 1e9)
    ctl.idle_until(START + 1e9)
    naps = []

    def pause(s):
        naps.append(s)
        wall.t += s
        if len(naps) == 1:
            sim.busy()                         # slowed during the nap: woken early, sleeps again

    sleeper = handle(path, wall, pause=pause)
    target = sleeper.now() + 20_000.0
    sleeper.sleep(20_000.0)
    assert naps[0] == pytest.approx(2.0)       # one exact nap at FAST
    assert sleeper.now() >= target
    assert sleeper.now() - target <= 1e-6 + SLICE_S * SLOW


def test_a_sleeper_across_the_limit_wakes_at_the_slow_part(path, wall):
    sim, ctl = handle(path, wall, "sim"), handle(path, wall, "controller")
    sim.idle_until(START + 10_000.0)
    ctl.idle_until(START + 1e9)
    sleeper = handle(path, wall, pause=lambda s: setattr(wall, "t", wall.t + s))
    sleeper.sleep(10_500.0)                    # 1 s at FAST, then 5 s at SLOW
    assert sleeper.now() == pytest.approx(START + 10_500.0, abs=1e-6)
    assert wall.t == pytest.approx(5_000.0 + 6.0)


def test_short_naps_are_floored_only_while_the_farm_runs_fast(path, wall):
    sim, ctl = handle(path, wall, "sim"), handle(path, wall, "controller")
    naps = []
    sleeper = handle(path, wall, pause=lambda s: (naps.append(s), setattr(wall, "t", wall.t + s)))
    sleeper.sleep(0.5)                         # slow: 5 ms of wall, exact
    assert naps == [pytest.approx(0.005)]
    sim.idle_until(START + 1e9)
    ctl.idle_until(START + 1e9)
    naps.clear()
    sleeper.sleep(0.5)                         # fast: 50 us of wall would spin; one floored nap
    assert naps == [pytest.approx(FAST_NAP_S)]


def test_wall_converts_on_the_current_segment(path, wall):
    sim, ctl = handle(path, wall, "sim"), handle(path, wall, "controller")
    sim.idle_until(START + 10_000.0)
    ctl.idle_until(START + 1e9)
    assert ctl.wall(5_000.0) == pytest.approx(0.5)
    assert ctl.wall(20_000.0) == pytest.approx(1.0 + 10_000.0 / SLOW)
    assert ctl.wall(1.0) == FAST_NAP_S         # fast: a 1-farm-s timeout is no spin
    sim.busy()
    assert ctl.wall(1.0) == pytest.approx(1.0 / SLOW)


def test_asleep_is_woken_by_a_speed_rise_on_the_real_wall(tmp_path):
    p = tmp_path / "clock"
    create(p, slow=SLOW, fast=FAST, farm_start=START, lease_s=0.0)
    sim, ctl = ElasticClock(p), ElasticClock(p)
    sim.claim("sim")
    ctl.claim("controller")
    ctl.idle_until(START + 1e9)

    async def run():
        target = ctl.now() + 500.0             # 5 wall s at SLOW
        t0 = time.monotonic()
        task = asyncio.ensure_future(ctl.asleep(500.0))
        await asyncio.sleep(0.05)
        sim.idle_until(START + 1e9)
        await task
        return target, time.monotonic() - t0

    target, took = asyncio.run(run())
    assert ctl.now() >= target
    assert took < 2.5                           # half of what the slow speed would have taken


def _sample(path: str, n: int, out) -> None:
    c = ElasticClock(path)
    rows = []
    for _ in range(n):
        w = time.time()
        rows.append((w, c.now(), time.time()))
        time.sleep(0.001)
    out.put(rows)


def test_readers_in_other_processes_agree_with_the_segments_written(tmp_path):
    p = tmp_path / "clock"
    create(p, slow=SLOW, fast=FAST, farm_start=START, lease_s=0.0)
    gov = ElasticClock(p)
    gov.claim("sim")
    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    readers = [ctx.Process(target=_sample, args=(str(p), 300, out)) for _ in range(3)]
    for r in readers:
        r.start()
    segments = [gov.segment()]
    deadline = time.time() + 30
    while any(r.is_alive() for r in readers) and time.time() < deadline:
        if len(segments) % 2:
            gov.idle_until(gov.now() + 5_000.0)
        else:
            gov.busy()
        segments.append(gov.segment())
        time.sleep(0.01)
        if out.qsize() == len(readers):
            break
    rows = [out.get(timeout=30) for _ in readers]
    for r in readers:
        r.join(timeout=30)
    def farm(w):                               # the timeline the segments drew
        return [s for s in segments if s.wall0 <= w][-1].farm_at(w)

    checked = 0
    for samples in rows:
        farms = [f for _w, f, _after in samples]
        assert farms == sorted(farms)
        for w0, f, w1 in samples:
            assert farm(w0) - 1e-3 <= f <= farm(w1) + 1e-3
            checked += 1
    assert checked == 900


def test_wall_since_is_the_wall_that_passed_not_the_lag_at_the_speed_now(path, wall):
    sim, ctl = handle(path, wall, "sim"), handle(path, wall, "controller")
    sim.idle_until(START + 1e9)
    ctl.idle_until(START + 1e9)
    readings = []
    for _ in range(200):                       # one wall second fast, read every 5 ms
        wall.t += 0.005
        readings.append((wall.t, ctl.now()))
    sim.busy()
    wall.t += 0.5                              # then half a second slow
    now = ctl.now()
    assert ctl.wall_since(now - 10.0) == pytest.approx(10.0 / SLOW)         # on the segment: exact
    for w, f in readings[::20]:                # before it: at least the wall since, within a reading's spacing
        assert wall.t - w - SEEN_EVERY_S - 1e-9 <= ctl.wall_since(f) <= wall.t - w + 1e-9
    assert ctl.wall(now - readings[0][1]) > 50.0    # what the lag at the slow speed says instead
    assert ctl.wall_since(now + 5.0) == 0.0
    fresh = handle(path, wall)                 # before anything it read: the rest at the slow speed
    assert fresh.wall_since(fresh.now() - 30.0 * SLOW) == pytest.approx(30.0)


def test_a_running_holder_is_asked_about_once_a_ttl_and_a_death_is_seen_within_it():
    """A renewal asked the kernel and /proc about every live holder, every 4 ms a process."""
    from devices.elastic_clock import RecentlyAlive
    running, asked, now = {11, 12}, [], [100.0]

    def ask(pid):
        asked.append(pid)
        return pid in running

    alive = RecentlyAlive(ask, ttl_s=0.1, now=lambda: now[0])
    assert alive(11) and alive(12) and not alive(13)
    for _ in range(50):                      # renewals within the ttl: nobody asked again
        now[0] += 0.001
        assert alive(11) and alive(12)
    assert asked == [11, 12, 13]
    running.discard(11)                      # 11 dies: seen once its ttl, counted from its last ask, is out
    now[0] = 100.0 + 0.1001
    assert not alive(11) and alive(12)
    assert not alive(11) and asked[-1] == 11 and asked.count(11) == 3   # the dead are asked every time


def test_the_clock_asks_through_the_cache_by_default(path, wall):
    from devices.elastic_clock import RecentlyAlive
    c = ElasticClock(path, wall_time=wall)
    try:
        assert isinstance(c._alive, RecentlyAlive) and c._alive.ask is process_alive
    finally:
        c.close()
