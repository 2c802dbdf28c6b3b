"""The pond cleaner's hardware-in-loop run, shared by hil_tests/test_cleaning.py (a small pond, in
CI) and bench/bench_cleaning_hil.py (the demo's 20 m x 10 m pond, to the end).

``fishfarm sim`` serves the thrusters (pty) and the tower camera (MJPEG over HTTP) and steps the
robot's physics; ``fishfarm run`` closes the loop camera -> float detection -> tracker -> state
machine -> path follower -> thrusters. The truth log traces the robot's real pose and thrust
(``[sim.pond] trace_s``); the ledger holds what the controller believes (its coverage map).
"""
from __future__ import annotations

import math
import sqlite3
import time
import types
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import Polygon

from hil_tests.demo_pond import sim_view, tower_file
from hil_tests.farm import HilFarm


def pond_farm(workdir: Path, *, speed: float, cleaning: dict | None = None, sim: dict | None = None,
              own_tower: bool = True, **kw) -> HilFarm:
    """A HilFarm of config/farm.toml with its cleaner, ``[cleaning]`` and ``[sim]`` overridden. With
    ``own_tower`` (a pond or camera size of the run's own) a TOWER.json of exactly the simulated
    camera the run will have; else the config's own (the demo's, from `fishfarm calibrate tower`)."""
    farm = HilFarm(workdir, speed=speed, cleaner=True, overrides={"cleaning": cleaning or {}, "sim": sim or {}},
                   **kw)
    c = farm.config
    if own_tower:
        view = sim_view(types.SimpleNamespace(sim=c["sim"], cleaning=c["cleaning"], path="hil"))
        c["cleaning"]["tower"] = str(tower_file(view, Path(workdir) / "TOWER.json"))
    return farm


def progress(farm: HilFarm) -> dict | None:
    """The cleaner's row in the ledger (read-only beside the controller), None before the first save."""
    try:
        with farm.ledger() as db:
            row = db.execute("SELECT run, path_index, state, mission, coverage, t FROM cleaner").fetchone()
    except sqlite3.OperationalError:               # no ledger, or no table yet
        return None
    return dict(row) if row is not None else None


def wait_progress(farm: HilFarm, done, timeout_s: float, what: str, poll_s: float = 0.05) -> dict:
    """Poll the ledger until ``done(row)``; AssertionError naming ``what`` after ``timeout_s`` wall."""
    deadline = time.time() + timeout_s
    row = None
    while time.time() < deadline:
        farm.check_alive()
        row = progress(farm)
        if row is not None and done(row):
            return row
        time.sleep(poll_s)
    raise AssertionError(f"{what}: not within {timeout_s:g} s (last saved: {row})\n{farm.log('controller.log')}")


@dataclass(frozen=True)
class Trace:
    """The robot's real motion from the truth log: farm time, pose and thrust per record."""
    t: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    thrust: np.ndarray          # (N, 2) left, right actually given

    @classmethod
    def of(cls, truth: list[dict]) -> Trace:
        rows = [r for r in truth if r["kind"] == "cleaner"]
        return cls(np.array([r["t"] for r in rows]), np.array([(r["x_m"], r["y_m"]) for r in rows]).reshape(-1, 2),
                   np.array([r["heading_rad"] for r in rows]), np.array([(r["left"], r["right"]) for r in rows]))

    def between(self, a: float, b: float) -> Trace:
        k = (self.t >= a) & (self.t <= b)
        return Trace(self.t[k], self.xy[k], self.heading[k], self.thrust[k])


def footprint(trace: Trace, outline, keepouts, body_m: float) -> dict:
    """How far the body's footprint (a disc of ``body_m``) ever reached beyond the pond's edge and
    into each keep-out (0 when never), over every traced pose."""
    pts = shapely.points(trace.xy)
    pond = Polygon(outline)
    inside = shapely.contains_xy(pond, trace.xy[:, 0], trace.xy[:, 1])
    edge = shapely.distance(pond.exterior, pts)
    out = np.where(inside, body_m - edge, body_m + edge)
    into = [body_m - shapely.distance(Polygon(k), pts) for k in keepouts]
    return {"poses": len(trace.t), "max_out_of_pond_m": round(max(0.0, float(out.max(initial=-1))), 4),
            "max_in_keepout_m": [round(max(0.0, float(d.max(initial=-1))), 4) for d in into]}


def watchdog_stop(trace: Trace, killed_t: float, until_t: float) -> dict:
    """After a SIGKILL at farm ``killed_t``: when the thrust the device gives reached zero on both
    sides, whether it stayed zero until ``until_t``, and the robot's speed over ground after."""
    after = trace.between(killed_t, until_t)
    idle = np.all(after.thrust == 0.0, axis=1)
    if not idle.any():
        return {"stopped_after_s": None, "stayed_stopped": False, "speed_after_m_s": None}
    first = int(np.argmax(idle))
    settled = after.between(after.t[first] + 3.0, until_t)     # the glide: mass / drag ~ 0.7 s
    steps = np.diff(settled.xy, axis=0)
    speed = float(np.max(np.hypot(*steps.T) / np.diff(settled.t), initial=0.0)) if len(settled.t) > 1 else None
    return {"stopped_after_s": round(float(after.t[first] - killed_t), 3), "stayed_stopped": bool(idle[first:].all()),
            "speed_after_m_s": None if speed is None else round(speed, 3)}


def truth_map(trace: Trace, geometry, settings: dict):
    """The coverage map the robot's real poses swept (controller/cleaning/coverage_map.py)."""
    from controller.cleaning.coverage_map import CoverageMap
    cmap = CoverageMap(geometry, cell_m=settings["cell_m"], brush_m=settings["brush_m"],
                       body_radius_m=settings["body_radius_m"])
    for i in range(1, len(trace.t)):
        (x0, y0), (x1, y1) = trace.xy[i - 1], trace.xy[i]
        cmap.sweep(x0, y0, x1, y1, trace.heading[i - 1], trace.heading[i])
    return cmap


def speed_over_ground(current_m_s) -> float:
    return math.hypot(*current_m_s)
