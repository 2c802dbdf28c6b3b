"""Where the tower camera can make the float out: the demo pond (config/farm.toml's outline, drain and
feeder; its scene seed, two distractors, glare 0.25, foam 0.05) rendered with the float every 0.5 m
at a random heading, each frame through JPEG as a camera streams it, then ``detect_float`` in the
tracker's window round the true position (``near``, 0.7 m) and over the whole frame.

Run: ``.venv/bin/python bench/bench_float_map.py [WIDTHxHEIGHT] [--quality Q] [--chroma 420|444]
[--seed S] [--map]``; prints one JSON object (``--map``: then a character map, far wall on top:
``.`` fixed, ``p`` position only, ``w`` heading off > 17 deg, ``W`` position off > 0.15 m, ``x`` none).
Figures: ``found``, ``good`` (within 0.15 m and 17 deg, a position-only fix counting on its position),
``pos_only``, ``pos_median_m``, heading median and p95 (fixes with a heading), ms per windowed call.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from devices.sim.pond_view import FloatPose, PondScene, tower_view  # noqa: E402
from vision.float_detect import detect_float  # noqa: E402

OUTLINE = [[0, 0], [20, 0], [20, 10], [0, 10]]
FEEDER = np.linspace(0, 2 * math.pi, 12, endpoint=False)
KEEPOUTS = [[[5, 3], [6, 3], [6, 4], [5, 4]], [[14 + 0.75 * math.cos(a), 6 + 0.75 * math.sin(a)] for a in FEEDER]]


def _error(fix, x, y, h):
    if fix is None:
        return None
    head = abs(math.remainder(fix.heading_rad - h, 2 * math.pi)) if fix.heading_known else None
    return math.hypot(fix.x_m - x, fix.y_m - y), head


def _stats(errors, n):
    got = [e for e in errors if e is not None]
    good = [e for e in got if e[0] < 0.15 and (e[1] is None or e[1] < 0.3)]
    heads = [e[1] for e in good if e[1] is not None]
    return {"found": round(len(got) / n, 4), "good": round(len(good) / n, 4),
            "pos_only": round(sum(e[1] is None for e in got) / n, 4),
            "pos_median_m": round(float(np.median([e[0] for e in good])), 4) if good else None,
            "heading_median_deg": round(float(np.degrees(np.median(heads))), 2) if heads else None,
            "heading_p95_deg": round(float(np.degrees(np.percentile(heads, 95))), 2) if heads else None}


def _mark(e):
    if e is None:
        return "x"
    if e[0] >= 0.15:
        return "W"
    if e[1] is None:
        return "p"
    return "." if e[1] < 0.3 else "w"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("size", nargs="?", default="1280x720")
    ap.add_argument("--quality", type=int, default=85)
    ap.add_argument("--chroma", choices=["420", "444"], default="420")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--map", action="store_true")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.split("x"))
    view = tower_view(OUTLINE, width=w, height=h)
    scene = PondScene(view, OUTLINE, KEEPOUTS, seed=a.seed, conditions={"distractors": 2, "glare": 0.25, "foam": 0.05})
    chroma = cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420 if a.chroma == "420" else cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444
    rng = np.random.default_rng(1)
    rows, window, whole, spent, t = {}, [], [], 0.0, 0.0
    for y in np.arange(0.5, 10, 0.5):
        for x in np.arange(0.5, 20, 0.5):
            heading = float(rng.uniform(-math.pi, math.pi))
            t += 0.37
            ok, buf = cv2.imencode(".jpg", scene.render(t, FloatPose(x, y, heading)),
                                   [cv2.IMWRITE_JPEG_QUALITY, a.quality, cv2.IMWRITE_JPEG_SAMPLING_FACTOR, chroma])
            img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
            began = time.thread_time()
            fix = detect_float(img, view.H, near=(x + rng.normal(0, 0.05), y + rng.normal(0, 0.05), 0.7))
            spent += time.thread_time() - began
            window.append(_error(fix, x, y, heading))
            whole.append(_error(detect_float(img, view.H), x, y, heading))
            rows.setdefault(float(y), []).append(_mark(window[-1]))
    n = len(window)
    out = {"size": [w, h], "quality": a.quality, "chroma": a.chroma, "seed": a.seed, "poses": n,
           "window": _stats(window, n), "whole_frame": _stats(whole, n), "window_cpu_ms": round(spent / n * 1000, 2)}
    print(json.dumps(out))
    if a.map:
        for y in sorted(rows, reverse=True):
            print(f"{y:5.1f} " + "".join(rows[y]))
    return out


if __name__ == "__main__":
    main()
