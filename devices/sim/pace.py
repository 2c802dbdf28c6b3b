"""The simulator's word to an elastic farm clock (devices/elastic_clock.py): busy while fish in any
tank ask for food, else idle until the next episode starts, less a lead so the first contacts and
the controller's detection run at the slow speed. The tanks know the next start ahead (hunger grows
at a known pace), so the clock slows at it by itself: the wall period of this loop only bounds how
soon the clock speeds up again after an episode, never how late it slows.

Turbulence and chatter need no fine time: contacts carry their farm timestamps, and the
controller's demand filter judges them by those, however late a fast clock delivers them.
"""
from __future__ import annotations

import asyncio

LEAD_S = 5.0             # farm s of slow time before an episode's first contact (the start is exact: a
                         # later one only comes of deaths lowering the appetite, which errs late)
PERIOD_S = 0.005         # wall s between looks


def declare(clock, tanks, lead_s: float = LEAD_S) -> None:
    now = clock.now()
    if not tanks or any(t.asking for t in tanks):
        clock.busy(why="fish asking" if tanks else "no tanks")
        return
    clock.idle_until(min(t.next_episode(now) for t in tanks) - lead_s, why="next episode")


async def pace(clock, tanks, lead_s: float = LEAD_S, period_s: float = PERIOD_S) -> None:
    tanks = [t for t in tanks if hasattr(t, "next_episode")]
    while True:
        declare(clock, tanks, lead_s)
        await asyncio.sleep(period_s)
