"""The pond cleaner's goal run on the real processes: the demo's 20 m x 10 m pond with a drain and a
feeder (config/farm.toml, its TOWER.json from `fishfarm calibrate tower`), `fishfarm sim` serving
the thrusters on a pty and the tower camera as MJPEG over HTTP, `fishfarm run` steering from the
frames; SIGKILLed when its map reaches 40 %, restarted at once, and run until the coverage path and
the mop-up after it (controller/cleaning/mopup.py) are done (state ``returning``) and the robot is
home (``docked``). ``lanes_done``: the same figures when the coverage path ended, before the mop-up.

Figures, measured on the robot's true poses from the simulator's truth log (every ``TRACE_S``):
- ``coverage``: reachable floor its brush swept / reachable floor (goal >= 0.98), the map swept
  from the true poses over the run (from the first ``cleaning`` to the mop-up's end);
  ``map_coverage``: what the controller's own map (the ledger) says;
- ``overlap``: path driven over floor already more than half cleaned / path driven (goal <= 0.10),
  coverage_map.py's measure;
- ``max_out_of_pond_m``, ``max_in_keepout_m``: deepest the body's footprint (0.35 m disc) reached
  beyond the edge / into each keep-out, over every traced pose (goal 0), while a controller ran
  and while none did (the robot then goes with the current: devices/sim/pond_physics.py);
- ``farm_s`` / ``wall_s``: time from the first ``cleaning`` to the path's end;
- ``resume``: coverage saved at the kill and taken up by the restarted controller, path index,
  the thrusters' watchdog stop (farm s after the kill) and the farm seconds until it cleaned again.

Run: ``.venv/bin/python bench/bench_cleaning_hil.py`` (about 22 minutes of wall); one JSON object.
``BENCH_CLEANER_KEEP=DIR`` keeps the run's logs, truth log and ledger in DIR to look into.
``BENCH_CLEANER_JPEG=Q`` sets the simulated camera's JPEG quality (default the demo's config/farm.toml);
``BENCH_CLEANER_SIZE=WxH`` its frame size (default the demo's 1280x720; at 640x360 the blue disc
along the far wall is 3 x 1.6 px) — with another size the run uses that camera's own exact TOWER.json.
"""
from __future__ import annotations

import contextlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil_tests.cleaning_run import (  # noqa: E402
    Trace,
    footprint,
    pond_farm,
    progress,
    truth_map,
    wait_progress,
    watchdog_stop,
)

# 0.15 farm s between frames at 20 frames/s; the frames the demo's size (its TOWER.json) unless asked
SPEED = float(os.environ.get("BENCH_CLEANER_SPEED", "3"))
FPS = float(os.environ.get("BENCH_CLEANER_FPS", "20"))
SMOKE = os.environ.get("BENCH_CLEANER_SMOKE") == "1"      # a quick look at the machinery, not the figures
JPEG = os.environ.get("BENCH_CLEANER_JPEG")
SIZE = os.environ.get("BENCH_CLEANER_SIZE")
KILL_AT = 0.02 if SMOKE else 0.40
UNTIL = 0.05 if SMOKE else 1.0                                # share of the coverage path's waypoints
ROOT = Path(__file__).resolve().parents[1]
TRACE_S = 0.05
LIMIT_WALL_S = float(os.environ.get("BENCH_CLEANER_LIMIT_S", "2400"))


def main() -> dict:
    from controller.cleaning.setup import prepare
    from controller.config import Config
    os.chdir(ROOT)                        # the config's paths (TOWER.json) are the repository's
    started = time.monotonic()
    keep = os.environ.get("BENCH_CLEANER_KEEP")          # a directory to keep the logs, truth and ledger in
    with (contextlib.nullcontext(keep) if keep else tempfile.TemporaryDirectory(prefix="bench-cleaner-")) as tmp:
        Path(tmp).mkdir(parents=True, exist_ok=True)
        size = dict(zip(("width", "height"), map(int, SIZE.split("x")), strict=True)) if SIZE else {}
        farm = pond_farm(Path(tmp), speed=SPEED, own_tower=bool(SIZE),
                         sim={"tower_camera": {"fps": FPS, **size, **({"jpeg_quality": int(JPEG)} if JPEG else {})},
                              "pond": {"trace_s": TRACE_S}})
        cfg = Config.model_validate({**farm.config, "path": "config/farm.toml"})
        prep = prepare(cfg)
        s = cfg.cleaning
        body = farm.config["sim"]["pond"].get("robot", {}).get("body_radius_m", 0.35)
        try:
            farm.start_sim()
            farm.start_controller()
            farm.wait_controller_up()
            first = wait_progress(farm, lambda r: r["state"] == "cleaning", 120.0, "cleaning begins")
            before = wait_progress(farm, lambda r: r["coverage"] >= KILL_AT, LIMIT_WALL_S, "40 % cleaned", 0.2)
            killed = farm.farm_now()
            farm.kill_controller()
            saved = progress(farm)
            farm.start_controller()
            farm.wait_controller_up()
            restarted = farm.farm_now()
            back = wait_progress(farm, lambda r: r["t"] > killed and r["run"] == saved["run"], 120.0,
                                 "the restarted controller's first save")
            cleaning_again = wait_progress(farm, lambda r: r["t"] > killed and r["state"] == "cleaning", 120.0,
                                           "cleaning again")
            lanes = wait_progress(farm, lambda r: r["path_index"] >= UNTIL * len(prep.plan.path), LIMIT_WALL_S,
                                  "the coverage path done", 0.2)
            done = lanes if SMOKE else wait_progress(farm, lambda r: r["state"] in ("returning", "docked"),
                                                     LIMIT_WALL_S, "the mop-up done", 0.2)
            done_wall = time.monotonic()
            home = done if SMOKE else wait_progress(farm, lambda r: r["state"] == "docked", 600.0, "home", 0.2)
        finally:
            farm.stop()
        trace = Trace.of(farm.truth())
    run = trace.between(first["t"], done["t"])
    down = trace.between(killed, cleaning_again["t"])
    keep = (trace.t < killed) | (trace.t > cleaning_again["t"])
    up = Trace(trace.t[keep], trace.xy[keep], trace.heading[keep], trace.thrust[keep])
    cleaned = truth_map(run, prep.geometry,
                        {"cell_m": s.cell_m, "brush_m": s.brush_m, "body_radius_m": s.body_radius_m})
    lanes_only = truth_map(trace.between(first["t"], lanes["t"]), prep.geometry,
                           {"cell_m": s.cell_m, "brush_m": s.brush_m, "body_radius_m": s.body_radius_m})
    camera = farm.config["sim"]["tower_camera"]
    return {"pond_m": [20, 10], "keepouts": len(s.keepouts), "speed": SPEED, "fps": FPS,
            "jpeg_quality": camera.get("jpeg_quality", 85),
            "camera": [camera["width"], camera["height"]],
            "current_m_s": farm.config["sim"]["pond"].get("robot", {}).get("current_m_s"),
            "plan_length_m": round(prep.plan.length_m, 1),
            "reachable_m2": round(cleaned.reachable.sum() * s.cell_m ** 2, 1),
            "goals": {"coverage": ">= 0.98", "overlap": "<= 0.10", "max_out_of_pond_m": 0, "max_in_keepout_m": 0},
            "coverage": round(cleaned.coverage(), 4), "overlap": round(cleaned.overlap(), 4),
            "map_coverage": round(done["coverage"], 4), "driven_m": round(cleaned.odometer_m, 1),
            "lanes_done": {"coverage": round(lanes_only.coverage(), 4), "overlap": round(lanes_only.overlap(), 4),
                           "map_coverage": round(lanes["coverage"], 4), "driven_m": round(lanes_only.odometer_m, 1),
                           "farm_s": round(lanes["t"] - first["t"], 1)},
            "mopup": {"max_m": s.mopup_max_m, "farm_s": round(done["t"] - lanes["t"], 1)},
            "controlled": footprint(up, s.outline, s.keepouts, body),
            "controller_down": footprint(down, s.outline, s.keepouts, body) if len(down.t) else None,
            "farm_s": round(done["t"] - first["t"], 1), "wall_s": round(done_wall - started, 1),
            "home_farm_s": round(home["t"] - done["t"], 1),
            "resume": {"killed_at_map_coverage": round(saved["coverage"], 4), "killed_path_index": saved["path_index"],
                       "resumed_coverage": round(back["coverage"], 4), "resumed_path_index": back["path_index"],
                       "same_run": back["run"] == saved["run"],
                       "restart_wall_s": round((restarted - killed) / SPEED, 1),
                       "cleaning_again_after_farm_s": round(cleaning_again["t"] - killed, 1),
                       "watchdog": watchdog_stop(trace, killed, restarted),
                       "coverage_before_kill": round(before["coverage"], 4)},
            "load": os.getloadavg()[0]}


if __name__ == "__main__":
    from bench import no_arguments

    no_arguments(__doc__)
    print(json.dumps(main()))
