"""Where the underwater survey's length bias comes from, by the fish's length in image pixels.

For each configuration (camera size, fish size) rendered scenes are measured and every report the
bench counts correct (``bench_survey_underwater.assign``) is compared with its fish's truth, end by
end and view by view, in the image: each end's error along the fish's true axis (px, positive =
outward: the snout beyond the true tip, the fork behind the true notch, so a positive sum reads
long) and across it, the image length error (px) and the 3-D length error (%). Results are binned
by the true length in the image (mean of the two views): 40-80, 80-160, 160-320, 320+ px.
Prints one JSON object.

Run: ``.venv/bin/python bench/diag_length_bias.py [--scenes 30] [--seed0 200000]
[--sizes 1280x960,640x480] [--lengths 9,25,drawn] [--params "..."] [--conditions "blur_gain=0.0"]
[--coverage 4] [--no-exact-edges] [--locator] [--pipeline 0]``
``--coverage``: fish drawn with their area coverage (``devices.sim.fish_render.COVERAGE``; OpenCV's
fill draws them ~0.5 px too big all round); ``--no-exact-edges``: with the coverage fill's own
half-sub-pixel overshoot (``fish_render.EXACT_EDGES``). ``--locator``: also the fork locator alone, started on
each fully visible fish's true fork (``locator_from_truth``: errors of the forks it places within 3 %).
(``drawn``: the scene's own species and sizes; a number: sparus_aurata of that mean fork length,
as the carriage's survey of a nursery tank renders it; the camera's focal length scales with its
width, as ``devices.sim.stereo_camera`` does.)
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import ast  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench.bench_survey_underwater import assign, parse_params  # noqa: E402
from devices.sim import fish_render  # noqa: E402
from devices.sim.fish_scene import underwater_rig, underwater_scene  # noqa: E402
from vision.fins import SPAN_OF_FL, Fins  # noqa: E402
from vision.fork import locate_forks, pyramid  # noqa: E402
from vision.survey_types import SurveySetup  # noqa: E402
from vision.underwater import Params, measure_underwater  # noqa: E402

BINS = (40.0, 80.0, 160.0, 320.0)


def end_errors(r, t) -> dict:
    """Per view (0 left, 1 right): each end's error along/across the true axis (px, outward
    positive), the image length error (px) and the true image length (px)."""
    out = {"snout_along": [], "snout_across": [], "fork_along": [], "fork_across": [], "len_px_err": [],
           "len_px": []}
    for c in (0, 1):
        axis = t.fork_px[c] - t.snout_px[c]
        n = float(np.linalg.norm(axis))
        a = axis / n
        perp = np.array([-a[1], a[0]])
        es, ef = r.snout_px[c] - t.snout_px[c], r.fork_px[c] - t.fork_px[c]
        out["snout_along"].append(float(-es @ a))
        out["snout_across"].append(float(es @ perp))
        out["fork_along"].append(float(ef @ a))
        out["fork_across"].append(float(ef @ perp))
        out["len_px_err"].append(float(np.linalg.norm(r.fork_px[c] - r.snout_px[c])) - n)
        out["len_px"].append(n)
    return out


def run(size: tuple[int, int], length: str, scenes: int, seed0: int, params: Params,
        fixed: dict | None = None) -> list[dict]:
    w, h = size
    rig = underwater_rig(image_size=(w, h), focal_px=1400.0 * w / 1280)
    setup = SurveySetup(up_world=(0.0, 0.0, 1.0))
    rows = []
    for seed in range(seed0, seed0 + scenes):
        cond = {} if length == "drawn" else {"species": "sparus_aurata", "mean_length_cm": float(length)}
        sc = underwater_scene(np.random.default_rng(seed), rig, **cond, **(fixed or {}))
        fish = measure_underwater(sc.left, sc.right, sc.rig.calibration(), setup, params=params)
        for k, ti, _, le in assign(fish, sc.fish, sc.rig.centres[0]):
            if ti < 0:
                continue
            e = end_errors(fish[k], sc.fish[ti])
            e["len_pct"] = 100 * le
            e["view_len_px"] = float(np.mean(e["len_px"]))
            rows.append(e)
    return rows


def locator_rows(size: tuple[int, int], length: str, scenes: int, seed0: int, fixed: dict | None = None) -> list[dict]:
    """The fork locator alone, as the survey runs it (twice: again from its own fork), started on
    each fully visible fish's true fork and axis with the span SPAN_OF_FL of its image length:
    its error along the true axis (px, positive behind the notch), per view."""
    w, h = size
    rig = underwater_rig(image_size=(w, h), focal_px=1400.0 * w / 1280)
    rows = []
    for seed in range(seed0, seed0 + scenes):
        cond = {} if length == "drawn" else {"species": "sparus_aurata", "mean_length_cm": float(length)}
        sc = underwater_scene(np.random.default_rng(seed), rig, **cond, **(fixed or {}))
        vis = [t for t in sc.fish if t.fully_visible]
        for c, img in enumerate((sc.left, sc.right)):
            if not vis:
                continue
            fork = np.array([t.fork_px[c] for t in vis])
            head = np.array([t.snout_px[c] for t in vis]) - fork
            n = np.linalg.norm(head, axis=1)
            fins = Fins(fork.copy(), np.arctan2(head[:, 1], head[:, 0]), SPAN_OF_FL * n, np.zeros(len(vis)),
                        np.ones(len(vis)))
            pyr = pyramid(img)
            first = locate_forks(pyr, fins)
            again = locate_forks(pyr, first.fins.take(np.flatnonzero(first.ok)))
            ok = np.flatnonzero(first.ok)[again.ok]
            e = again.fins.xy[again.ok] - fork[ok]
            a = -head[ok] / n[ok, None]
            for k in range(len(ok)):
                rows.append({"fork_along": [float(e[k] @ a[k])], "view_len_px": float(n[ok[k]]),
                             "fork_across": [float(e[k] @ [-a[k, 1], a[k, 0]])]})
    return rows


def _stat(v: list[float]) -> dict:
    v = np.asarray(v, float)
    if len(v) == 0:
        return {}
    return {"mean": round(float(v.mean()), 3), "median": round(float(np.median(v)), 3),
            "se": round(float(v.std(ddof=1) / np.sqrt(len(v))), 3) if len(v) > 1 else None}


def summary(rows: list[dict]) -> dict:
    """Per bin of image length: the ends' errors (both views pooled; per view too for the ends
    along the axis), the image length error in px and % of the image length, the 3-D length error."""
    out = {}
    edges = (*BINS, np.inf)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = [r for r in rows if lo <= r["view_len_px"] < hi]
        if not sel:
            continue
        name = f"{int(lo)}-{int(hi)}" if np.isfinite(hi) else f"{int(lo)}+"
        b = {"reports": len(sel)}
        for key in ("snout_along", "snout_across", "fork_along", "fork_across", "len_px_err"):
            b[key] = _stat([x for r in sel for x in r[key]])
        for key in ("snout_along", "fork_along"):
            for c, view in ((0, "left"), (1, "right")):
                b[f"{key}_{view}"] = _stat([r[key][c] for r in sel])["mean"]
        b["len_px_err_pct"] = _stat([100 * e / n for r in sel for e, n in zip(r["len_px_err"], r["len_px"],
                                                                                strict=True)])
        b["len_pct"] = _stat([r["len_pct"] for r in sel])
        out[name] = b
    return out


def _conditions(text: str) -> dict:
    """Scene conditions from 'name=value,...' (values as Python literals)."""
    out = {}
    for item in filter(None, re.split(r",(?=\s*\w+\s*=)", text)):
        key, value = item.split("=")
        out[key.strip()] = ast.literal_eval(value.strip())
    return out


def locator_summary(rows: list[dict]) -> dict:
    out = {}
    edges = (*BINS, np.inf)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = [r for r in rows if lo <= r["view_len_px"] < hi]
        if sel:
            name = f"{int(lo)}-{int(hi)}" if np.isfinite(hi) else f"{int(lo)}+"
            near = [r["fork_along"][0] for r in sel if abs(r["fork_along"][0]) <= 0.03 * r["view_len_px"]]
            out[name] = {"views": len(sel), "within_3pct": len(near), "fork_along_within": _stat(near),
                         "fork_across": _stat([r["fork_across"][0] for r in sel])}
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=30)
    ap.add_argument("--seed0", type=int, default=200000)
    ap.add_argument("--sizes", default="1280x960,640x480")
    ap.add_argument("--lengths", default="9,25,drawn")
    ap.add_argument("--params", default="")
    ap.add_argument("--locator", action="store_true", help="also the fork locator alone, from the true forks")
    ap.add_argument("--pipeline", type=int, default=1, help="0: the locator alone (with --locator)")
    ap.add_argument("--coverage", type=int, default=fish_render.COVERAGE,
                    help="fish drawn with their area coverage at this supersampling (devices.sim.fish_render.COVERAGE)")
    ap.add_argument("--no-exact-edges", action="store_true",
                    help="the coverage fill's half-sub-pixel overshoot left in (devices.sim.fish_render.EXACT_EDGES)")
    ap.add_argument("--conditions", default="", help="scene conditions fixed, e.g. 'blur_gain=0.0,noise_sd=1.0'")
    args = ap.parse_args()
    params = parse_params(args.params) or Params()
    fixed = _conditions(args.conditions)
    fish_render.COVERAGE = args.coverage
    fish_render.EXACT_EDGES = not args.no_exact_edges
    cv2.setNumThreads(1)
    out = {"scenes": args.scenes, "seed0": args.seed0, "params": args.params, "conditions": fixed,
           "coverage": args.coverage, "exact_edges": fish_render.EXACT_EDGES,
           "configs": {}}
    pooled = []
    for s in args.sizes.split(","):
        size = tuple(int(x) for x in s.split("x"))
        for length in args.lengths.split(","):
            rows = run(size, length, args.scenes, args.seed0, params, fixed) if args.pipeline else []
            pooled += rows
            out["configs"][f"{s}_{length}"] = {"reports": len(rows),
                                               "len_pct": _stat([r["len_pct"] for r in rows]),
                                               "bins": summary(rows)}
    out["pooled_bins"] = summary(pooled)
    if args.locator:
        loc = []
        for s in args.sizes.split(","):
            for length in args.lengths.split(","):
                loc += locator_rows(tuple(int(x) for x in s.split("x")), length, args.scenes, args.seed0, fixed)
        out["locator_from_truth"] = locator_summary(loc)
    out["load"] = os.getloadavg()[0]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
