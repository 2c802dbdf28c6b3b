"""Tower camera renderer speed: ms per frame of PondScene.render on one core (goal <= 20 ms at 1280x720).

Run: ``.venv/bin/python bench/bench_pond_view.py [--frames 120]``; prints one JSON object:
per frame size and scenario the median wall and CPU ms per frame (float, distractors, occluders
and all), the scene's one-off setup in s, and ``baseline_ms``: a 5x5 Gaussian blur of a colour
frame of that size timed in the same run, so figures from a loaded machine can be compared as
ratios. OpenCV is held to one thread, so a frame is rendered on one core (whichever the
scheduler finds free; ``ms_cpu`` is that thread's CPU time, immune to other processes' load).
"""
from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from devices.sim.pond_view import scenario  # noqa: E402

SIZES = ((1280, 720), (1920, 1080))
SCENES = ("straight", "distractors", "foam", "glare", "washover", "dropouts")


def _time(fn, n: int) -> tuple[float, float]:
    wall, cpu = [], []
    for i in range(n):
        w0, c0 = time.perf_counter(), time.thread_time()
        fn(i)
        wall.append(time.perf_counter() - w0)
        cpu.append(time.thread_time() - c0)
    return round(statistics.median(wall) * 1e3, 2), round(statistics.median(cpu) * 1e3, 2)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=120)
    a = ap.parse_args()
    cv2.setNumThreads(1)
    out: dict = {"load_avg_1m": round(os.getloadavg()[0], 2), "frames": a.frames, "sizes": {}}
    for w, h in SIZES:
        img = np.random.default_rng(0).integers(0, 255, (h, w, 3), dtype=np.uint8)
        size = {"baseline_ms": _time(lambda _, img=img: cv2.GaussianBlur(img, (5, 5), 0), 50)[0], "scenes": {}}
        for name in SCENES:
            t0 = time.perf_counter()
            scene, track = scenario(name, width=w, height=h, duration_s=a.frames / 25.0)
            setup = time.perf_counter() - t0
            wall, cpu = _time(lambda i, s=scene, tr=track: s.render(tr[i][0], tr[i][1], occlusion=tr[i][2]), len(track))
            size["scenes"][name] = {"ms_wall": wall, "ms_cpu": cpu, "setup_s": round(setup, 2),
                                    "ratio_to_baseline": round(wall / size["baseline_ms"], 2)}
        med = statistics.median(s["ms_wall"] for s in size["scenes"].values())
        size["median_ms_wall"] = med
        out["sizes"][f"{w}x{h}"] = size
    out["goal_1280x720_ms"] = 20.0
    out["ok"] = out["sizes"]["1280x720"]["median_ms_wall"] <= 20.0
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
