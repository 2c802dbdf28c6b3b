"""Chessboard calibration benchmark on OpenCV's real stereo sample (13 pairs, 9x6 corners).

Run: ``.venv/bin/python bench/bench_chessboard.py``; prints one JSON object: our RMS and mean
epipolar error against OpenCV's stereo_calib procedure on the same images, and the square size
reconstructed in 3-D (median over all neighbouring corners) against the size we calibrated with.
Data: ../shared/data/stereo-chessboard next to the repository.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from vision.chessboard import calibrate_pairs, find_corners, reference_stereo_calib, square_sizes

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "stereo-chessboard"
PATTERN = (9, 6)
SQUARE_MM = 25.0


def main() -> None:
    if not DATA.is_dir():
        print(json.dumps({"benchmark": "chessboard", "skipped": f"no data at {DATA}"}))
        sys.exit(0)
    left = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(DATA.glob("left*.jpg"))]
    right = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(DATA.glob("right*.jpg"))]
    t0 = time.perf_counter()
    ref = reference_stereo_calib(left, right, PATTERN)
    t_ref = time.perf_counter() - t0
    t0 = time.perf_counter()
    corners = [[find_corners(img, PATTERN) for img in side] for side in (left, right)]
    ours = calibrate_pairs(*corners, left[0].shape[::-1], PATTERN, SQUARE_MM)
    t_ours = time.perf_counter() - t0
    sizes = np.concatenate([square_sizes(ours.calibration, a, b, PATTERN)
                            for a, b in zip(ours.corners1, ours.corners2, strict=True)])
    out = {
        "benchmark": "chessboard", "pairs": len(left),
        "pairs_used": sum(p.used for p in ours.pairs),
        "rms_px": round(ours.rms_px, 4), "opencv_rms_px": round(ref["rms_px"], 4),
        "epipolar_px": round(ours.epipolar_px, 4), "opencv_epipolar_px": round(ref["epipolar_px"], 4),
        "epipolar_ratio_to_opencv": round(ours.epipolar_px / ref["epipolar_px"], 3),
        "goal_epipolar_ratio_max": 1.05,
        "baseline_squares": round(ours.baseline_squares, 4),
        "opencv_baseline_squares": round(ref["baseline_squares"], 4),
        "square_mm_calibrated": SQUARE_MM,
        "square_mm_reconstructed_median": round(float(np.median(sizes)), 4),
        "square_size_error_pct": round(100 * (float(np.median(sizes)) / SQUARE_MM - 1), 4),
        "square_size_spread_pct_p5_p95": [round(100 * (float(np.percentile(sizes, q)) / SQUARE_MM - 1), 3)
                                          for q in (5, 95)],
        "goal_square_error_pct_max": 0.5,
        "seconds": round(t_ours, 3), "opencv_seconds": round(t_ref, 3),
    }
    out["goals_met"] = (out["epipolar_ratio_to_opencv"] <= 1.05 and abs(out["square_size_error_pct"]) <= 0.5)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from bench import no_arguments

    no_arguments(__doc__)
    main()
