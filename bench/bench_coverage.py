"""Pond-cleaning closed loop: coverage planner -> pure pursuit -> pond physics, and a resume.

Run: ``.venv/bin/python bench/bench_coverage.py [--seed 0] [--current 0.04 0.02]``; prints one JSON object.

The pond: 20 m x 10 m with two keep-outs, a drain (1 m x 1 m square) and a feeder (disc 1.5 m
across). Robot: body radius 0.35 m, brush 0.5 m, physics of devices/sim/pond_physics.py at 50 Hz
with a current that makes it crab; the pose reaches the follower at 10 Hz with 3 cm / 2 deg of
noise (the tower camera and tracker's figures), and the controller's coverage map is marked from
those measured poses, as on the farm. What the robot really cleaned is a second map marked from
the physics' true poses; the goals are measured on it:
- ``coverage``: cleaned reachable floor / reachable floor (geometry.py; goal >= 0.98);
- ``overlap``: path length whose brush swath was already more than half cleaned (cells cleaned
  before the last brush width of path) / total path length (coverage_map.py; goal <= 0.10);
- ``max_out_of_pond_m`` / ``max_in_keepout_m``: the deepest the body's footprint (disc of the
  body radius) ever reached beyond the pond's edge or into a keep-out, checked at every physics
  step (goal 0); ``keepout_clearance_m`` / ``edge_clearance_m``: the least gap left between the
  body and a keep-out / the pond's edge; ``band_s``: farm seconds the body was nearer a keep-out
  than ``BAND_M`` (the geofence's band at a typical pose); ``bumps``: physics steps a wall stopped (the walls hold
  the robot, so the pond's edge cannot be crossed: a bump is a try, and the edge pass runs along
  the walls on purpose);
- ``farm_s``: farm time to finish. ``resume``: the same run stopped (SIGKILL-like) when the
  controller's map reaches 40 %, restarted from the last state it had persisted (every 5 s: the map
  bytes and the follower's progress) after 5 s with thrusters off, drifting in the current.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import shapely

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from controller.cleaning.coverage import plan_coverage  # noqa: E402
from controller.cleaning.coverage_map import CoverageMap  # noqa: E402
from controller.cleaning.geometry import disc, pond_geometry  # noqa: E402
from controller.cleaning.steering import PathFollower  # noqa: E402
from devices.sim.pond_physics import CleanerParams, PondRobot  # noqa: E402

POND = [(0, 0), (20, 0), (20, 10), (0, 10)]
KEEPOUTS = [[(5, 3), (6, 3), (6, 4), (5, 4)], disc(14, 6, 0.75)]
BRUSH_M, BODY_M = 0.5, 0.35
PHYS_DT, POSE_DT = 0.02, 0.1
NOISE_M, NOISE_RAD = 0.03, math.radians(2)
PERSIST_S, DOWN_S = 5.0, 5.0
LIMIT_S = 4 * 3600.0
BAND_M = 0.07          # the geofence's band at a typical pose: 0.03 m + 2 x the tracker's ~0.02 m std


class Loop:
    def __init__(self, geom, plan, params, seed):
        self.geom, self.plan, self.rng = geom, plan, np.random.default_rng(seed + 1)
        p0, p1 = plan.path[0], plan.path[1]
        self.robot = PondRobot(params, POND, *p0, math.atan2(*(p1 - p0)[::-1]), seed=seed)
        self.follower = PathFollower(plan.path, track_m=params.track_m, period_s=POSE_DT)
        self.belief = CoverageMap(geom, brush_m=BRUSH_M, body_radius_m=BODY_M)
        self.truth = CoverageMap(geom, brush_m=BRUSH_M, body_radius_m=BODY_M)
        self.t, self.trace, self.saved, self.last_save = 0.0, [], None, -math.inf
        self.measured = None

    def measure(self):
        r = self.robot
        return (r.x + self.rng.normal(0, NOISE_M), r.y + self.rng.normal(0, NOISE_M),
                math.remainder(r.heading + self.rng.normal(0, NOISE_RAD), 2 * math.pi))

    def physics(self, left, right):
        r = self.robot
        before = (r.x, r.y, r.heading)
        for _ in range(round(POSE_DT / PHYS_DT)):
            r.step(PHYS_DT, left, right)
            self.trace.append((r.x, r.y))
        self.truth.sweep(before[0], before[1], r.x, r.y, before[2], r.heading)
        self.t += POSE_DT

    def run(self, stop=lambda loop: False):
        while not self.follower.done and self.t < LIMIT_S and not stop(self):
            pose = self.measure()
            if self.measured is not None:
                self.belief.sweep(*self.measured[:2], *pose[:2], self.measured[2], pose[2])
            self.measured = pose
            left, right = self.follower.command(*pose)
            self.physics(left, right)
            if self.t - self.last_save >= PERSIST_S:
                self.saved, self.last_save = (self.belief.to_bytes(), self.follower.progress), self.t

    def restart(self):
        """The controller dies: thrusters stop (device watchdog), it comes back with what it stored."""
        for _ in range(round(DOWN_S / POSE_DT)):
            self.physics(0.0, 0.0)
        data, progress = self.saved
        self.belief = CoverageMap.from_bytes(self.geom, data, brush_m=BRUSH_M, body_radius_m=BODY_M)
        self.follower = PathFollower(self.plan.path, period_s=POSE_DT, start_index=progress)
        self.measured = None

    def figures(self) -> dict:
        xy = np.array(self.trace)
        pts = shapely.points(xy)
        edge = shapely.distance(self.geom.outline.exterior, pts)
        inside = shapely.contains_xy(self.geom.outline, xy[:, 0], xy[:, 1])
        out = np.max(np.where(inside, BODY_M - edge, BODY_M + edge))
        gap = np.min([shapely.distance(k, pts) for k in self.geom.keepouts], axis=0) - BODY_M
        into = float(-np.min(gap))
        edge_gap = float(np.min(np.where(inside, edge, -edge)) - BODY_M)
        return {"coverage": round(self.truth.coverage(), 4), "overlap": round(self.truth.overlap(), 4),
                "map_coverage": round(self.belief.coverage(), 4), "max_out_of_pond_m": round(max(0.0, out), 3),
                "max_in_keepout_m": round(max(0.0, into), 3), "keepout_clearance_m": round(-into, 3),
                "edge_clearance_m": round(edge_gap, 3), "band_s": round(float(np.sum(gap < BAND_M)) * PHYS_DT, 1),
                "bumps": self.robot.bumps,
                "farm_s": round(self.t, 1), "driven_m": round(self.truth.odometer_m, 1),
                "finished": bool(self.follower.done)}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--current", type=float, nargs=2, default=(0.04, 0.02), metavar=("VX", "VY"))
    args = ap.parse_args(argv)
    geom = pond_geometry(POND, KEEPOUTS)
    started = time.perf_counter()
    plan = plan_coverage(geom, brush_m=BRUSH_M, body_radius_m=BODY_M, start_xy=(0.5, 0.5))
    plan_s = time.perf_counter() - started
    params = CleanerParams(current_m_s=tuple(args.current), body_radius_m=BODY_M)
    whole = Loop(geom, plan, params, args.seed)
    whole.run()
    resumed = Loop(geom, plan, params, args.seed)
    resumed.run(stop=lambda loop: loop.belief.coverage() >= 0.40)
    stopped_at = {"farm_s": round(resumed.t, 1), "map_coverage": round(resumed.belief.coverage(), 4),
                  "saved_progress": resumed.saved[1]}
    resumed.restart()
    resumed.run()
    return {"pond_m": [20, 10], "brush_m": BRUSH_M, "body_radius_m": BODY_M, "current_m_s": list(args.current),
            "plan": {"length_m": round(plan.length_m, 1), "lanes": plan.lanes, "turns": plan.turns,
                     "angle_deg": round(math.degrees(plan.angle_rad), 1), "plan_s": round(plan_s, 3),
                     "reachable_m2": round(geom.reachable(BODY_M, BRUSH_M).area, 2)},
            "goals": {"coverage": ">= 0.98", "overlap": "<= 0.10", "max_out_of_pond_m": 0, "max_in_keepout_m": 0},
            "run": whole.figures(), "resume": {"stopped": stopped_at, **resumed.figures()},
            "wall_s": round(time.perf_counter() - started, 1)}


if __name__ == "__main__":
    print(json.dumps(main()))
