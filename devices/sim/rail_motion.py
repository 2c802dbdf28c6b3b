"""The simulated rail's motion: trapezoidal profiles (accelerate, cruise, decelerate) planned as a
few constant-acceleration phases from the carriage's position *and velocity* at a command's instant,
so a new target, a stop or an e-stop in mid-travel is exact, and position is a closed-form function
of farm time (``devices.sim.rail``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Phase:
    """Constant acceleration ``a`` for ``dur`` seconds from (t0, p0, v0)."""

    t0: float
    p0: float
    v0: float
    a: float
    dur: float

    def at(self, t: float) -> tuple[float, float]:
        dt = min(max(t - self.t0, 0.0), self.dur)
        return self.p0 + self.v0 * dt + 0.5 * self.a * dt * dt, self.v0 + self.a * dt


@dataclass(frozen=True, slots=True)
class Profile:
    """A planned motion: phases back to back, then rest at ``p_end`` from ``t_end`` on."""

    phases: tuple[Phase, ...]
    t_end: float
    p_end: float

    @classmethod
    def rest(cls, t: float, p: float) -> Profile:
        return cls((), t, p)

    @property
    def start(self) -> float:
        """The command instant it was planned from."""
        return self.phases[0].t0 if self.phases else self.t_end

    def cuts(self) -> list[float]:
        """Instants where the acceleration changes: between them the carriage goes one way."""
        return [ph.t0 for ph in self.phases] + [self.t_end]

    def at(self, t: float) -> tuple[float, float]:
        if t >= self.t_end:
            return self.p_end, 0.0
        for ph in self.phases:          # at most four phases
            if t < ph.t0 + ph.dur:
                return ph.at(t)
        return self.p_end, 0.0


def _chain(t: float, p: float, v: float, legs: list[tuple[float, float]],
           p_end: float | None = None) -> Profile:
    """Phases from (t, p, v) through ``legs`` of (acceleration, duration); zero-length legs dropped."""
    phases = []
    for a, dur in legs:
        if dur <= 0:
            continue
        ph = Phase(t, p, v, a, dur)
        phases.append(ph)
        t += dur
        p, v = ph.at(t)
    return Profile(tuple(phases), t, p if p_end is None else p_end)


def plan_stop(t: float, p: float, v: float, decel: float) -> Profile:
    """Brake at ``decel`` to rest."""
    return _chain(t, p, v, [(-math.copysign(decel, v), abs(v) / decel)])


def plan_move(t: float, p: float, v: float, target: float, vmax: float, accel: float) -> Profile:
    """Trapezoid (or triangle) from (p, v) to rest at ``target``, never faster than ``vmax``.

    Moving away from the target, or too fast to stop before it, the drive first brakes to
    rest and plans again from there."""
    head = Profile.rest(t, p)
    if v != 0 and (v * (target - p) < 0 or v * v / (2 * accel) > abs(target - p) + 1e-12):
        head = plan_stop(t, p, v, accel)
        t, p, v = head.t_end, head.p_end, 0.0
    d = target - p
    s = math.copysign(1.0, d)
    dist, u = abs(d), abs(v)
    vp = min(vmax, math.sqrt(accel * dist + u * u / 2))            # peak speed: cruise if vmax caps it
    d_ramp = abs(vp * vp - u * u) / (2 * accel)
    d_brake = vp * vp / (2 * accel)
    cruise = max(dist - d_ramp - d_brake, 0.0)
    legs = [(s * accel * math.copysign(1.0, vp - u), abs(vp - u) / accel),
            (0.0, cruise / vp if vp > 0 else 0.0),
            (-s * accel, vp / accel)]
    tail = _chain(t, p, v, legs, p_end=target)
    return Profile(head.phases + tail.phases, tail.t_end, target)
