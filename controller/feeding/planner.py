"""Which waiting tank to serve next.

Each raised demand must see its auger start within a deadline (60 s). Serving the oldest
first wastes travel when demands cluster at both ends of the rail; serving the nearest first
can starve a tank. For the handful of tanks that wait at once, look one step ahead: try each
as the next stop, finish the rest oldest-first, and keep the order whose latest start is least
late. Travel and dispensing times are estimates from the rail's cruise speed and the auger's
learned rate; they only rank orders, they do not promise times.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Stop:
    tank: str
    position_m: float
    raised_t: float       # farm s
    dispense_s: float     # estimated auger time here


def travel_s(a_m: float, b_m: float, speed_m_s: float, accel_m_s2: float) -> float:
    """Trapezoid (or triangle) move time between two points on the rail."""
    d = abs(b_m - a_m)
    ramp = speed_m_s * speed_m_s / accel_m_s2          # distance to reach cruise and stop again
    if d >= ramp:
        return d / speed_m_s + speed_m_s / accel_m_s2
    return 2.0 * (d / accel_m_s2) ** 0.5


def _lateness(order: list[Stop], position_m: float, now: float, deadline_s: float, speed: float,
              accel: float) -> float:
    t, pos, worst = now, position_m, float("-inf")
    for stop in order:
        t += travel_s(pos, stop.position_m, speed, accel)
        worst = max(worst, t - (stop.raised_t + deadline_s))
        t += stop.dispense_s
        pos = stop.position_m
    return worst


def next_stop(stops: list[Stop], position_m: float, now: float, *, deadline_s: float = 60.0,
              speed_m_s: float = 1.0, accel_m_s2: float = 0.5) -> Stop | None:
    """The stop to make first so that the latest auger start is as little late as possible."""
    if len(stops) <= 1:
        return stops[0] if stops else None
    by_age = sorted(stops, key=lambda s: s.raised_t)
    best, best_key = None, None
    for first in stops:
        order = [first] + [s for s in by_age if s is not first]
        late = _lateness(order, position_m, now, deadline_s, speed_m_s, accel_m_s2)
        key = (max(late, 0.0), abs(first.position_m - position_m), first.raised_t)
        if best_key is None or key < best_key:
            best, best_key = first, key
    return best
