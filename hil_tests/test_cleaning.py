"""The pond cleaner in the loop: the real controller steers the simulated robot from the simulated
tower camera's frames, over the real thrusters' serial line and an MJPEG stream, is SIGKILLed
mid-run and restarted. A small pond (8 m x 5 m, a drain and a feeder) keeps it within a minute of
wall time; bench/bench_cleaning_hil.py runs the demo's 20 m x 10 m pond to the end.

Still water here, so that this one-minute run judges the loop itself: the crabbing current is the
bench's (the demo's [sim.pond]), bench_coverage's and bench_cleaning_loop's. (The floor grips a
robot whose thrusters are off — devices/sim/pond_physics.py — so a current no longer carries it
while the controller starts or is killed.)"""
import math
import os

import pytest

from controller.cleaning.geometry import disc
from hil_tests.cleaning_run import Trace, footprint, pond_farm, progress, wait_progress, watchdog_stop

# 0.2 farm s between frames at 20 frames/s: the follower's step (bench_coverage runs it at 0.1 s)
SPEED = float(os.environ.get("FISHFARM_HIL_CLEANER_SPEED", "4"))
OUTLINE = [[0.0, 0.0], [8.0, 0.0], [8.0, 5.0], [0.0, 5.0]]
KEEPOUTS = [[[2.0, 1.5], [2.8, 1.5], [2.8, 2.3], [2.0, 2.3]],          # the drain
            [list(p) for p in disc(5.5, 3.2, 0.5, points=12)]]          # the feeder's foot
DOCK = [0.8, 0.8]
WATCHDOG_S = 1.0           # config/farm.toml [devices.thrusters]
RAMP_S = 0.25              # the twin ramps full thrust to zero in 1 / ramp_per_s (4 /s)
TRACE_S = 0.1
STEP_S = 0.02              # [sim.pond] step_s: the trace is taken at the end of a physics step
BODY_M = 0.35              # config/farm.toml [sim.pond] robot body_radius_m: the physical footprint
FIRST_SHARE = 0.08         # coverage saved before the kill
MORE_SHARE = 0.04          # and cleaned after the restart


@pytest.mark.hil
def test_the_cleaner_cleans_stays_clear_is_stopped_by_the_watchdog_and_resumes(tmp_path):
    farm = pond_farm(tmp_path, speed=SPEED,
                     cleaning={"outline": OUTLINE, "keepouts": KEEPOUTS, "dock": DOCK, "autostart": True,
                               "save_every_s": 2.0, "lost_after_s": 8.0},
                     sim={"tower_camera": {"width": 640, "height": 360, "fps": 20},
                          "pond": {"trace_s": TRACE_S,
                                   "robot": {"current_m_s": [0.0, 0.0], "body_radius_m": BODY_M}}})
    try:
        farm.start_sim()
        farm.start_controller()
        farm.wait_controller_up()
        before = wait_progress(farm, lambda r: r["coverage"] >= FIRST_SHARE, 40.0, "coverage rising")
        assert before["state"] == "cleaning" and before["mission"] == "clean", before
        killed = farm.farm_now()
        farm.kill_controller()
        saved = progress(farm)                 # what the dead controller left in the ledger
        farm.sleep_until_farm(killed + WATCHDOG_S + RAMP_S + 4.0)
        restarted = farm.farm_now()
        farm.start_controller()
        farm.wait_controller_up()
        first = wait_progress(farm, lambda r: r["t"] > restarted, 30.0, "the restarted controller's first save")
        after = wait_progress(farm, lambda r: r["coverage"] >= saved["coverage"] + MORE_SHARE, 30.0,
                              "cleaning on after the restart")
        farm.check_alive()
    finally:
        farm.stop()
    trace = Trace.of(farm.truth())
    # the loop closed: coverage rose from nothing, the robot really moved
    assert saved["coverage"] >= before["coverage"] - 1e-9 and saved["coverage"] >= FIRST_SHARE
    assert float(abs(trace.xy - trace.xy[0]).max()) > 1.0
    # never out of the pond, never into a keep-out: every traced pose, the body's whole footprint
    clear = footprint(trace, OUTLINE, KEEPOUTS, BODY_M)
    assert clear["poses"] >= 100 and clear["max_out_of_pond_m"] == 0.0, clear
    assert clear["max_in_keepout_m"] == [0.0, 0.0], clear
    # SIGKILLed while driving: the device's watchdog stopped both thrusters within watchdog_s of the
    # last drive (before the kill), the ramp down and a trace interval; they stayed stopped, and the robot
    # came to rest
    stop = watchdog_stop(trace, killed, restarted)
    print({"saved": saved, "first_after_restart": first, "after": after, "footprint": clear, "watchdog": stop})
    assert stop["stopped_after_s"] is not None, stop
    assert stop["stopped_after_s"] <= WATCHDOG_S + RAMP_S + TRACE_S + STEP_S, stop
    assert stop["stayed_stopped"] and stop["speed_after_m_s"] < 0.02, stop
    driving = trace.between(killed - 2.0, killed)
    assert (abs(driving.thrust) > 0.05).any(), "the robot was not driving when killed: the watchdog went untested"
    # the restart resumed the map it had saved (same run, coverage not back to 0) and went on cleaning
    assert first["run"] == saved["run"] and first["coverage"] >= saved["coverage"] - 1e-9, (saved, first)
    assert first["path_index"] >= saved["path_index"], (saved, first)
    assert after["coverage"] >= saved["coverage"] + MORE_SHARE and after["state"] in ("cleaning", "returning"), after
    moved = trace.between(restarted, math.inf)
    assert float(abs(moved.xy - moved.xy[0]).max()) > 0.5
