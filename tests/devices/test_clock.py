"""The manual clock: sleepers wake when a test moves time, and cost nothing while they wait."""
from __future__ import annotations

import asyncio
import selectors
import threading

import pytest

from devices.clock import ManualClock, ScaledClock


class CountingSelector(selectors.DefaultSelector):
    """Counts how often the event loop wakes up to look for work."""

    wakeups = 0

    def select(self, timeout=None):
        self.wakeups += 1
        return super().select(timeout)


def run(main):
    selector = CountingSelector()
    loop = asyncio.SelectorEventLoop(selector)
    try:
        return loop.run_until_complete(main(selector))
    finally:
        loop.close()


def test_idle_sleepers_do_not_wake_the_loop_and_advance_wakes_exactly_the_due_ones():
    async def main(selector):
        clock = ManualClock()
        woke: list[int] = []

        async def sleeper(i):
            await clock.asleep(10.0 * (i + 1))
            woke.append(i)

        tasks = [asyncio.create_task(sleeper(i)) for i in range(10)]
        await asyncio.sleep(0)                       # every sleeper is waiting now
        before = selector.wakeups
        idle = asyncio.get_running_loop().create_future()
        asyncio.get_running_loop().call_later(0.05, idle.set_result, None)
        await idle                                   # an idle spell: nobody should look at the clock
        idle_wakeups = selector.wakeups - before
        clock.advance(30.0)
        await asyncio.wait_for(asyncio.gather(*tasks[:3]), 2.0)
        early = sorted(woke)
        clock.advance(1000.0)
        await asyncio.wait_for(asyncio.gather(*tasks), 2.0)
        return idle_wakeups, early, sorted(woke)

    idle_wakeups, early, woke = run(main)
    # the idle spell itself needs one or two; polling sleepers would need ~100
    assert idle_wakeups <= 3
    assert early == [0, 1, 2]
    assert woke == list(range(10))


def test_advance_from_another_thread_and_setting_t_wake_sleepers():
    async def main(_selector):
        clock = ManualClock(t=0.0)
        first = asyncio.create_task(clock.asleep(5.0))
        await asyncio.sleep(0)
        threading.Thread(target=clock.advance, args=(5.0,)).start()
        await asyncio.wait_for(first, 2.0)
        second = asyncio.create_task(clock.asleep(5.0))
        await asyncio.sleep(0)
        clock.t = 10.0                              # tests that jump the clock by assignment
        await asyncio.wait_for(second, 2.0)
        return clock

    clock = run(main)
    assert clock.now() == 10.0 and not clock._sleepers


def test_cancelled_and_zero_sleeps_leave_no_sleeper_behind():
    async def main(_selector):
        clock = ManualClock()
        task = asyncio.create_task(clock.asleep(100.0))
        await asyncio.sleep(0)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        await clock.asleep(0.0)
        await clock.asleep(-3.0)
        return clock

    clock = run(main)
    assert not clock._sleepers


def test_a_sleeper_whose_loop_is_gone_does_not_break_advance():
    clock = ManualClock()

    async def abandon():
        asyncio.create_task(clock.asleep(50.0))      # never awaited: asyncio.run cancels it
        await asyncio.sleep(0)

    asyncio.run(abandon())
    clock.advance(100.0)                             # must not raise on the closed loop
    assert clock.now() == pytest.approx(1_780_000_100.0)


def test_the_wall_clock_goes_to_a_child_without_epochs_outside_the_farm_s_years():
    """``real()``'s epochs are 0 (1970): handed on as flags, the child refused them."""
    from controller.cli.params import FARM_INSTANT
    assert ScaledClock.real().as_args() == ["--speed", "1.0"]
    fast = ScaledClock.starting(60.0, 1_780_000_000.0)
    args = fast.as_args()
    assert args[::2] == ["--speed", "--epoch-wall", "--epoch-farm"]
    for value in args[3::2]:
        FARM_INSTANT.convert(value, None, None)          # within the farm's years
