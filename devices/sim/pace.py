"""The simulator's word to an elastic farm clock (devices/elastic_clock.py): busy while fish in any
tank ask for food, else idle until the next episode starts, less a lead so the first contacts and
the controller's detection run at the slow speed. The tanks know the next start ahead (hunger grows
at a known pace), so the clock slows at it by itself: the wall period of this loop only bounds how
soon the clock speeds up again after an episode, never how late it slows.

Fish asking are busy for ``ATTENTION_S`` from their episode's start or their last meal: the
demand and its service come within that (the contract: a demand within 60 s; 180 s for the slow
fish the filter takes longer over). Fish that ask on past it are not being fed (their tank's
ration is reached, or it is paused): they need no fine time until they could start again after
giving up and resting. A demand the controller raises later slows the clock at once from its side.

Where the simulator hears the controller's demands (``heard``: tank id -> farm time a demand for
it was last heard), fish are busy only until one is heard after their start or last meal: the
controller then holds the clock slow itself for as long as it acts on it (the demand waiting, the
robot moving and dispensing), and a demand it turns down (the tank's ration reached) needs no fine
time. Over half of a grow-out's episodes were such unfed ones (285 of 518 in 14 days), each
holding the clock slow for the whole ``ATTENTION_S`` while nothing happened.

Turbulence and chatter need no fine time: contacts carry their farm timestamps, and the
controller's demand filter judges them by those, however late a fast clock delivers them.
"""
from __future__ import annotations

import asyncio
import math

LEAD_S = 5.0             # farm s of slow time before an episode's first contact (the start is exact
                         # between meals but for deaths: they lower the appetite and, with meals_per_day,
                         # the hunger that starts an episode with it, which brings the start a little
                         # earlier -- at 0.05 %/day well under a second an hour, inside this lead while
                         # the pacer looks every PERIOD_S)
PERIOD_S = 0.005         # wall s between looks
ATTENTION_S = 180.0      # farm s fish asking hold the clock slow after their start or last meal


def needs_slow_from(tank, now: float, attention_s: float = ATTENTION_S, heard_t: float = -math.inf) -> float:
    """The farm time from which ``tank`` needs the slow clock (``now`` or earlier: it does now);
    ``heard_t``: the farm time a demand for it was last heard (the controller took it over)."""
    if not tank.asking:
        return tank.next_episode(now)
    if now < tank.heeded_t + attention_s and heard_t < tank.heeded_t:
        return now
    return tank.unheeded_until()


def declare(clock, tanks, lead_s: float = LEAD_S, attention_s: float = ATTENTION_S, heard=None) -> None:
    """``heard``: tank id -> farm time a demand for it was last heard (-inf: none), or None."""
    if not tanks:
        clock.busy(why="no tanks")
        return
    now = clock.now()
    t = min(needs_slow_from(tank, now, attention_s, -math.inf if heard is None else heard(tank.id))
            for tank in tanks)
    if t <= now:
        clock.busy(why="fish asking")
    else:
        clock.idle_until(t - lead_s, why="next episode" if not any(k.asking for k in tanks) else "unheeded fish")


async def pace(clock, tanks, lead_s: float = LEAD_S, period_s: float = PERIOD_S, heard=None) -> None:
    tanks = [t for t in tanks if hasattr(t, "next_episode")]
    while True:
        declare(clock, tanks, lead_s, heard=heard)
        await asyncio.sleep(period_s)
