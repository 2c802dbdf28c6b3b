"""Stereo benchmark: DLT calibration accuracy on the simulated rig, triangulation throughput.

Run: ``.venv/bin/python bench/bench_stereo.py [--seeds 20] [--pairs 1000000]``; prints one JSON
object. Throughput is measured pinned to one CPU with BLAS limited to one thread.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")         # before numpy loads: "one core" means one core

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from devices.sim.stereo_rig import (  # noqa: E402
    convergent_rig,
    measure_grid,
    random_points_in_grid_volume,
    two_plane_object,
)
from vision.dlt import calibrate_stereo, distance_errors_pct, error_summary  # noqa: E402
from vision.triangulation import triangulate  # noqa: E402

GRID_NOISE_PX = 0.2
CHECK_NOISE_PX = 0.02


def accuracy(seeds: int, validation_points: int = 100) -> dict:
    """Per seed: calibrate from the 100-point grid at 0.2 px, then measure the distances between
    random validation points (pixels at 0.02 px) in the grid's volume."""
    rig, world = convergent_rig(), two_plane_object()
    runs, truth_runs, reports = [], [], []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        grid = measure_grid(rig, world, GRID_NOISE_PX, rng)
        P1, P2, report = calibrate_stereo(grid[:, :3], grid[:, 3:5], grid[:, 5:7])
        check = random_points_in_grid_volume(world, validation_points, rng)
        v1, v2 = rig.project(check, CHECK_NOISE_PX, rng)
        runs.append(error_summary(distance_errors_pct(check, triangulate(P1, P2, v1, v2)[0])))
        truth_runs.append(error_summary(distance_errors_pct(check, triangulate(rig.P1, rig.P2, v1, v2)[0])))
        reports.append(report.distance_error_pct | {"rms_px": max(report.rms_px)})

    def stat(rows, key, fn):
        return round(float(fn([r[key] for r in rows])), 5)

    return {
        "grid_points": len(world), "grid_noise_px": GRID_NOISE_PX, "validation_points": validation_points,
        "validation_noise_px": CHECK_NOISE_PX, "seeds": seeds,
        "validation_distance_error_pct": {
            "median": stat(runs, "median", np.median), "p95": stat(runs, "p95", np.median),
            "max": stat(runs, "max", np.median),
            "worst_seed_median": stat(runs, "median", np.max), "worst_seed_p95": stat(runs, "p95", np.max)},
        "true_matrices_validation_error_pct": {
            "median": stat(truth_runs, "median", np.median), "p95": stat(truth_runs, "p95", np.median)},
        "grid_report_distance_error_pct": {
            "median": stat(reports, "median", np.median), "p95": stat(reports, "p95", np.median),
            "max": stat(reports, "max", np.median)},
        "grid_report_rms_px": stat(reports, "rms_px", np.median),
    }


def throughput(n: int, repeats: int = 5) -> dict:
    rig = convergent_rig()
    rng = np.random.default_rng(0)
    world = random_points_in_grid_volume(two_plane_object(), n, rng)
    p1, p2 = rig.project(world, 0.2, rng)
    out = {"pairs": n}
    for iterations in (0, 1):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            triangulate(rig.P1, rig.P2, p1, p2, iterations=iterations)
            times.append(time.perf_counter() - t0)
        key = "pairs_per_s" if iterations == 0 else "pairs_per_s_reweighted"
        out[key] = round(n / float(np.median(times)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--pairs", type=int, default=1_000_000)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    result = {"calibration": accuracy(args.seeds), "triangulation": throughput(args.pairs)}
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
