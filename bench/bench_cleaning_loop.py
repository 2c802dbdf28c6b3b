"""The cleaner's live loop without processes: bench_coverage's pond and physics, but the pose as
the real loop gets it.

Run: ``.venv/bin/python bench/bench_cleaning_loop.py [--frame-s 0.15] [--latency-s 0.1] [--no-geofence]
[--cruise 0.6] [--lookahead 1.0] [--blind X Y R ...] [--no-recovery]``; prints one JSON object.

What differs from bench_coverage: a camera frame every ``--frame-s`` farm s (jittered +-30 %; the
demo's 20 frames/s wall at 3x farm speed is 0.15 s), the float's true pose at the frame's instant
plus detection noise (3 cm, 2 deg), reaching the controller ``--latency-s`` later (render, MJPEG,
detection); the real FloatTracker (vision/float_track.py) over those fixes; the follower's command
through the geofence (controller/cleaning/geofence.py, unless --no-geofence) and then the
thrusters as the simulated device runs them (ramp 4/s, watchdog 0.5 s: both stop when no drive
comes). The controller's map is swept from tracked poses, as cleaner.py does; the goals are
measured on the true poses (bench_coverage.Loop.figures).

``--blind X Y R`` (repeatable): a disc of the pond where the camera cannot make the float out (a
far wall, a tarp under it): no fix while the float is over it but for a share ``--blind-seen`` of
its ``--blind-cell`` (0.2) m cells (fixed: a robot stopped on a blind cell stays unseen). The
tracker goes predicted, then lost; the cleaner's recovery (controller/cleaning/recovery.py; off
with ``--no-recovery``) backs the robot up along its trail after 5 s of lost. ``recovery`` in the
output: how many ran and how they ended; ``lost_s``: farm s spent lost.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.bench_coverage import BODY_M, BRUSH_M, KEEPOUTS, LIMIT_S, NOISE_M, NOISE_RAD, PHYS_DT, POND, Loop  # noqa: E402
from controller.cleaning import mopup  # noqa: E402
from controller.cleaning.coverage import (  # noqa: E402
    KEEPOUT_MARGIN,  # noqa: E402
    plan_coverage,
)
from controller.cleaning.geofence import Geofence  # noqa: E402
from controller.cleaning.geometry import pond_geometry  # noqa: E402
from controller.cleaning.recovery import Recovery  # noqa: E402
from controller.cleaning.steering import PathFollower  # noqa: E402
from controller.config import CleaningConfig  # noqa: E402
from devices.sim.pond_physics import CleanerParams  # noqa: E402
from vision.float_detect import FloatFix  # noqa: E402
from vision.float_track import FloatTrack, FloatTracker  # noqa: E402

WATCHDOG_S = 0.5
OVERLAP = 0.05                 # plan_coverage's default, which this bench plans with
_DEFAULTS = CleaningConfig.model_fields
MOPUP_M, MOPUP_S = _DEFAULTS["mopup_max_m"].default, _DEFAULTS["mopup_max_s"].default   # the farm's defaults


class Thrust:
    """The simulated device's output: ramps towards the target; the watchdog zeroes it."""
    def __init__(self, ramp_per_s: float = 4.0):
        self.ramp = ramp_per_s
        self.now = np.zeros(2)
        self.target = np.zeros(2)
        self.since = 0.0

    def drive(self, left, right):
        self.target[:] = left, right
        self.since = 0.0

    def step(self, dt):
        self.since += dt
        if self.since > WATCHDOG_S:
            self.target[:] = 0.0
        self.now += np.clip(self.target - self.now, -self.ramp * dt, self.ramp * dt)
        return self.now


def seen_at(x, y, share, cell_m):
    """Whether the camera makes the float out over this cell of a blind spot: a fixed ``share`` of
    the cells, the same every frame (a robot stopped on a blind cell stays unseen)."""
    h = (int(x // cell_m) * 73856093) ^ (int(y // cell_m) * 19349663)
    return (h % 1000) / 1000 < share


class LiveLoop(Loop):
    def __init__(self, geom, plan, params, seed, args):
        super().__init__(geom, plan, params, seed)
        self.args = args
        self.follower = PathFollower(plan.path, track_m=params.track_m, period_s=args.frame_s,
                                     lookahead_m=args.lookahead, cruise=args.cruise)
        self.tracker = FloatTracker()
        self.fence = None if args.no_geofence else Geofence.for_pond(geom, BODY_M, latency_s=args.latency_s)
        self.thrust = Thrust(args.ramp)
        self.pending = []              # (arrival t, frame t, fix)
        self.steered = None
        self.max_gap_s = 0.0
        self.recovery = (None if args.no_recovery
                         else Recovery(gaps=None if self.fence is None else self.fence.gaps))
        self.lost_s, self.lost_at = 0.0, None
        self.mopup = None              # the cleaner's mop-up once the lanes are done (mopup.py)
        self.lanes_done = None         # figures when the boustrophedon path ended

    def finished(self):
        return self.follower.done and (self.args.mopup_m <= 0 or (self.mopup is not None and self.mopup.done))

    def steer(self, x, y, heading, dt, refused):
        """The cleaner's _steer in ``cleaning``: the path, then the mop-up (cleaner.py)."""
        if not self.follower.done:
            command = self.follower.command(x, y, heading, dt_s=dt, refused=refused)
            if not self.follower.done:
                return command
        if self.args.mopup_m <= 0:
            return 0.0, 0.0
        if self.mopup is None:
            self.lanes_done = {"coverage": round(self.truth.coverage(), 4), "overlap": round(self.truth.overlap(), 4),
                               "map_coverage": round(self.belief.coverage(), 4),
                               "driven_m": round(self.truth.odometer_m, 1), "farm_s": round(self.t, 1)}
            drive, router = mopup.spaces(self.geom, BODY_M, KEEPOUT_MARGIN)
            self.mopup = mopup.begin(self.belief, drive, router, (x, y),
                                     lambda path, i: PathFollower(path, period_s=self.args.frame_s,
                                                                  lookahead_m=self.args.lookahead,
                                                                  cruise=self.args.cruise, start_index=i),
                                     brush_m=BRUSH_M, spacing_m=BRUSH_M * (1 - OVERLAP), max_m=self.args.mopup_m,
                                     max_s=self.args.mopup_s)
        command = self.mopup.command(x, y, heading, dt_s=dt, refused=refused)
        return (0.0, 0.0) if command is None else command

    def step_physics(self):
        r = self.robot
        before = (r.x, r.y, r.heading)
        r.step(PHYS_DT, *self.thrust.step(PHYS_DT))
        self.trace.append((r.x, r.y))
        self.truth.sweep(before[0], before[1], r.x, r.y, before[2], r.heading)
        self.t += PHYS_DT

    def run(self, stop=lambda loop: False):
        a, rng = self.args, self.rng
        next_frame = 0.0
        while not self.finished() and self.t < a.limit_s and not stop(self):
            if self.t >= next_frame:
                x, y, h = self.measure()
                r = self.robot
                seen = (all(math.dist((r.x, r.y), b[:2]) > b[2] for b in a.blind)
                        or seen_at(r.x, r.y, a.blind_seen, a.blind_cell))
                self.pending.append((self.t + a.latency_s, self.t, FloatFix(x, y, h, 0.9) if seen else None))
                next_frame = self.t + a.frame_s * rng.uniform(0.7, 1.3)
            while self.pending and self.pending[0][0] <= self.t:
                _, t_frame, fix = self.pending.pop(0)
                self.on_fix(t_frame, fix)
            self.step_physics()

    def on_fix(self, t_frame, fix):
        track = self.tracker.step(t_frame, fix)
        lost = track.state == "lost"       # the cleaner's ``lost`` (no machine here)
        if self.lost_at is not None:
            self.lost_s += t_frame - self.lost_at
        self.lost_at = t_frame if lost else None
        if self.recovery is not None:
            self.recovery.note(track, lost)
            back = self.recovery.command(t_frame) if lost else None
            if back is not None:
                self.thrust.drive(*back)
        if self.args.raw_pose and fix is not None:   # the detector's fix itself, as bench_coverage steers on
            track = FloatTrack(t_frame, fix.x_m, fix.y_m, fix.heading_rad, "tracking", NOISE_M, track.speed_m_s)
        if track.state == "tracking":
            if self.measured is not None:
                self.belief.sweep(*self.measured[:2], track.x_m, track.y_m, self.measured[2], track.heading_rad)
            self.measured = (track.x_m, track.y_m, track.heading_rad)
        if track.x_m is None:
            return
        dt = None if self.steered is None else max(1e-3, t_frame - self.steered)
        self.steered = t_frame
        refused = 0 if self.fence is None else self.fence.streak
        command = self.steer(track.x_m, track.y_m, track.heading_rad, dt, refused)
        if self.fence is not None:
            command = self.fence.check(track, command, t_frame)
        self.thrust.drive(*command)

    def figures(self):
        out = super().figures()
        if self.fence is not None:
            out.update(geofence_refused=self.fence.refused, geofence_blind=self.fence.blind,
                       geofence_backed_off=self.fence.backed_off, waypoints_skipped=self.follower.skipped)
        out["lost_s"] = round(self.lost_s, 1)
        if self.mopup is not None:
            metres, seconds = self.mopup.spent()
            out["mopup"] = {"lanes_done": self.lanes_done, "passes": len(self.mopup.plan.passes),
                            "planned_m": round(self.mopup.plan.length_m, 1), "aimed_cells": self.mopup.plan.aimed,
                            "out_of_reach_cells": self.mopup.plan.out_of_reach, "driven_m": round(metres, 1),
                            "farm_s": round(seconds, 1), "given_up_cells": int(self.belief.given_up.sum())}
        if self.recovery is not None:
            out["recovery"] = {"runs": self.recovery.runs, **self.recovery.ended}
        return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--current", type=float, nargs=2, default=(0.04, 0.02), metavar=("VX", "VY"))
    ap.add_argument("--frame-s", type=float, default=0.15)
    ap.add_argument("--latency-s", type=float, default=0.1)
    ap.add_argument("--cruise", type=float, default=0.6)
    ap.add_argument("--lookahead", type=float, default=1.0)
    ap.add_argument("--no-geofence", action="store_true")
    ap.add_argument("--ramp", type=float, default=4.0, help="thrusters' ramp, fraction of full thrust per s")
    ap.add_argument("--blind", type=float, nargs=3, action="append", default=[], metavar=("X", "Y", "R"),
                    help="no fix while the float is within R m of (X, Y)")
    ap.add_argument("--blind-seen", type=float, default=0.0,
                    help="share of the blind spots' cells where it is made out")
    ap.add_argument("--blind-cell", type=float, default=0.2, help="m: the blind spots' cells")
    ap.add_argument("--limit-s", type=float, default=LIMIT_S, help="farm s before the run is called off")
    ap.add_argument("--no-recovery", action="store_true", help="wait when lost, as before recovery.py")
    ap.add_argument("--mopup-m", type=float, default=MOPUP_M, help="the mop-up's cap, m (0: none)")
    ap.add_argument("--mopup-s", type=float, default=MOPUP_S, help="the mop-up's cap, farm s")
    ap.add_argument("--raw-pose", action="store_true", help="steer on the fixes, not the tracker's output")
    args = ap.parse_args(argv)
    geom = pond_geometry(POND, KEEPOUTS)
    started = time.perf_counter()
    plan = plan_coverage(geom, brush_m=BRUSH_M, body_radius_m=BODY_M, start_xy=(0.5, 0.5))
    loop = LiveLoop(geom, plan, CleanerParams(current_m_s=tuple(args.current), body_radius_m=BODY_M),
                    args.seed, args)
    loop.run()
    return {"frame_s": args.frame_s, "latency_s": args.latency_s, "cruise": args.cruise, "ramp": args.ramp,
            "raw_pose": args.raw_pose, "blind": args.blind, "blind_seen": args.blind_seen,
            "blind_cell": args.blind_cell, "recovery": not args.no_recovery,
            "mopup_m": args.mopup_m,
            "lookahead_m": args.lookahead, "geofence": not args.no_geofence,
            "noise": [NOISE_M, round(math.degrees(NOISE_RAD), 1)], "current_m_s": list(args.current),
            "goals": {"coverage": ">= 0.98", "overlap": "<= 0.10", "max_in_keepout_m": 0},
            "run": loop.figures(), "wall_s": round(time.perf_counter() - started, 1)}


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1:])))
