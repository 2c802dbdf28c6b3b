"""Detection and tracking on the simulated tower camera's frames (devices/sim/pond_view.py), at a
size and rate the bench does not use: short stretches of the hard scenarios, every visible frame
checked against the renderer's ground truth. (The long runs and the figures are bench/bench_tracking.py.)"""
import math

import pytest

from devices.sim.pond_view import scenario
from vision.float_track import FloatTracker, track_frame


@pytest.mark.parametrize("name, start", [("washover", 6.0)])   # the rest: bench/bench_tracking.py
def test_every_visible_frame_tracked_to_goal_accuracy(name, start):
    scene, track = scenario(name, seed=5, width=960, height=540, fps=10.0, duration_s=start + 2.5)
    tracker = FloatTracker()
    errs, heads = [], []
    for t, pose, occ in track:
        if t < start:
            continue
        tk, _ = track_frame(tracker, t, scene.render(t, pose, occlusion=occ), scene.view.H)
        if pose is not None and occ < 0.5:
            assert tk.state in ("tracking", "predicted") and tk.x_m is not None, (t, tk)
            errs.append(math.hypot(tk.x_m - pose.x_m, tk.y_m - pose.y_m))
            heads.append(abs(math.remainder(tk.heading_rad - pose.heading_rad, 2 * math.pi)))
    assert len(errs) >= 20
    assert math.sqrt(sum(e * e for e in errs) / len(errs)) <= 0.05 and max(errs) < 0.15
    assert math.degrees(math.sqrt(sum(h * h for h in heads) / len(heads))) <= 5.0
