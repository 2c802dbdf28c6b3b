"""Matching benchmark: 1,000 points along epipolar bands of a 1280x960 pair, on one core.

Run: ``.venv/bin/python bench/bench_matching.py [--repeats 15]``; prints one JSON object.
The pair is a textured plane rendered through the paper's convergent rig (devices/sim). Times are
process CPU time (robust on a shared machine) and wall time, medians over the repeats, pinned to
one CPU with OpenCV and BLAS on one thread. The headline configuration: 11x11 windows, +-1 px band,
a working window of 130 mm in depth (~65 px along the line). Beside it, ``whole_range_900_1400mm``:
the same search over the rig's whole working range (~217 px along the line). ``goal_met`` needs
both within ``goal_ms``.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")         # before numpy loads: "one core" means one core

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from devices.sim.stereo_rig import convergent_rig  # noqa: E402
from devices.sim.stereo_scene import textured_plane  # noqa: E402
from vision.epipolar import fundamental_from_projections  # noqa: E402
from vision.matching import match_points, segments_by_range  # noqa: E402
from vision.triangulation import triangulate  # noqa: E402

GOAL_MS = 50.0
WINDOW_MM = 130.0


def scene(seed: int = 1, points: int = 1000):
    rig = convergent_rig()
    rng = np.random.default_rng(seed)
    c1, c2 = rig.centres
    sc = textured_plane(rig.P1, rig.P2, rig.image_size, rig.target, (c1 + c2) / 2 - rig.target, rng)
    pts1 = rng.uniform([0, 0], [1279, 959], (4 * points, 2))
    truth = sc.truth(pts1)
    seen = np.all((truth >= 8) & (truth <= [1271, 951]), axis=1)       # the match is in image 2
    pts1, truth = pts1[seen][:points], truth[seen][:points]
    depth = np.linalg.norm(triangulate(rig.P1, rig.P2, pts1, truth)[0] - c1, axis=1)
    # a WINDOW_MM working window that holds the surface somewhere inside it, not always at its centre
    near = depth - rng.uniform(10, WINDOW_MM - 10, len(pts1))
    return sc, rig, pts1, truth, near


def run(sc, pts1, truth, F, segments, repeats: int, **kw) -> dict:
    match_points(sc.img1, sc.img2, pts1, F, segments=segments, **kw)            # warm-up
    cpu, wall = [], []
    for _ in range(repeats):
        t0, w0 = time.process_time(), time.perf_counter()
        r = match_points(sc.img1, sc.img2, pts1, F, segments=segments, **kw)
        cpu.append(time.process_time() - t0)
        wall.append(time.perf_counter() - w0)
    err = np.linalg.norm(r.pts2 - truth, axis=1)[r.valid]
    span = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    return {"ms_cpu_median": round(1e3 * float(np.median(cpu)), 2),
            "ms_wall_median": round(1e3 * float(np.median(wall)), 2),
            "ms_cpu_min": round(1e3 * float(np.min(cpu)), 2),
            "span_px_median": round(float(np.median(span)), 1),
            "valid_fraction": round(float(r.valid.mean()), 3),
            "error_px_median": round(float(np.median(err)), 3),
            "error_px_p90": round(float(np.percentile(err, 90)), 3),
            "gross_errors_over_1_5px": int((err > 1.5).sum()),
            "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in kw.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    cv2.setNumThreads(1)
    sc, rig, pts1, truth, near = scene()
    F = fundamental_from_projections(rig.P1, rig.P2)
    window = segments_by_range(rig.P1, rig.P2, pts1, near, near + WINDOW_MM)
    working = segments_by_range(rig.P1, rig.P2, pts1, 900.0, 1400.0)       # the rig's whole range
    head = run(sc, pts1, truth, F, window, args.repeats, patch=11, band_px=1.0)
    whole = run(sc, pts1, truth, F, working, args.repeats, patch=11, band_px=1.0)
    out = {"benchmark": "matching", "points": len(pts1), "image": [1280, 960], "threads": 1,
           "goal_ms": GOAL_MS, "goal_met": max(head["ms_cpu_median"], whole["ms_cpu_median"]) <= GOAL_MS,
           **head,
           "whole_range_900_1400mm": whole,
           "variants": {
               "band_0": run(sc, pts1, truth, F, window, args.repeats, patch=11, band_px=0.0),
               "scales_3": run(sc, pts1, truth, F, window, args.repeats, patch=11, band_px=1.0,
                               scales=(0.8, 1.0, 1.25))}}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
