"""Where the underwater survey loses fish: for every fully visible rendered fish, the first stage
it does not pass. Prints one JSON object.

Run: ``.venv/bin/python bench/diag_underwater.py [--scenes 20] [--seed0 0] [--params "min_score=0.12"]
[--conditions '{"clutter": "reef"}']`` (``--conditions``: the scenes' conditions given, the rest drawn)
(``--params``: ``vision.underwater.Params`` fields to change, e.g. ``outlines=False,min_score=0.12,
max_epipolar=1e9`` for the pipeline before the silhouettes).

Stages (each judged in image pixels against ``FishTruth.fork_px`` / ``snout_px``, tolerances as
fractions of the fish's fork length in that image):
``proposed``  a fork hypothesis within 10 % of the true fork, in the left and the right image;
``located``   a located fork (after the transfer along epipolar lines) within 3 %, in both;
``paired``    a left-right fork pair with both ends within 3 %;
``snout``     for that pair, a snout candidate within 3 % of the true snout in both images;
``associated`` the pair's chosen snouts within 3 % in both and the pair kept by the filters;
``filtered``  a report the bench counts correct (bench_survey_underwater.assign): lost here, the fish
             was dropped by the post-filters (score, epipolar consistency, one fish per snout) or
             its 3-D placement is outside the bench's tolerance.
``by_length_px``: the same funnel for each third of the fish by their length in the left image.
``located_why``: for the fish lost at ``located``, per image that has no located fork within 3 %,
what the learned locator answered from the hypotheses within 10 % of the true fork: ``misplaced``
(sure, at least ``Params.net_min_conf``, but more than 3 % off), ``unsure`` (within 3 % but less
sure), ``both`` (neither, or no hypothesis there), ``dropped`` (within 3 % and sure, but not kept:
a duplicate's, or beaten by a nearby fork; the fork may still come from the transfer along the
epipolar line).
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import ast  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench.bench_survey_underwater import assign  # noqa: E402
from devices.sim.fish_scene import underwater_scene  # noqa: E402
from vision import fork_net  # noqa: E402
from vision.survey_types import SurveySetup  # noqa: E402
from vision.underwater import Params, measure_underwater  # noqa: E402

STAGES = ("proposed", "located", "paired", "snout", "associated", "filtered")
PROPOSE_TOL = 0.10
TOL = 0.03


def _near(pts: np.ndarray, target: np.ndarray, tol_px: float) -> np.ndarray:
    pts = np.asarray(pts, float).reshape(-1, 2)
    if len(pts) == 0:
        return np.zeros(0, bool)
    return np.linalg.norm(pts - target, axis=1) <= tol_px


def fish_stage(t, tr: dict, reported_ok: bool) -> str:
    """The first stage fish ``t`` fails, or ``"found"`` (a fish the bench counts found is found,
    whatever the pixel checks say: its tolerances are in 3-D)."""
    if reported_ok:
        return "found"
    fl = [np.linalg.norm(t.snout_px[c] - t.fork_px[c]) for c in (0, 1)]
    if not all(_near(tr["proposed"][c], t.fork_px[c], PROPOSE_TOL * fl[c]).any() for c in (0, 1)):
        return "proposed"
    located = tr.get("located", [np.zeros((0, 2))] * 2)
    if not all(_near(located[c], t.fork_px[c], TOL * fl[c]).any() for c in (0, 1)):
        return "located"
    p1, p2 = tr.get("pairs", (np.zeros((0, 2)), np.zeros((0, 2))))
    pair = _near(p1, t.fork_px[0], TOL * fl[0]) & _near(p2, t.fork_px[1], TOL * fl[1])
    if not pair.any():
        return "paired"
    if "snouts" not in tr:
        return "snout"
    a1, a2 = tr["associated"][:2]
    rows = np.flatnonzero(_near(a1, t.fork_px[0], TOL * fl[0]) & _near(a2, t.fork_px[1], TOL * fl[1]))
    s1, s2 = tr["snouts"]
    if not any(_near(s1[r], t.snout_px[0], TOL * fl[0]).any() and _near(s2[r], t.snout_px[1], TOL * fl[1]).any()
               for r in rows):
        # the right snout may also come from the transfer along the left one's epipolar line
        c1, c2 = tr["associated"][2:4]
        if not any(_near(c1[r], t.snout_px[0], TOL * fl[0]).any() and _near(c2[r], t.snout_px[1], TOL * fl[1]).any()
                   for r in rows):
            return "snout"
    c1, c2, keep = tr["associated"][2:]
    if not any(keep[r] and _near(c1[r], t.snout_px[0], TOL * fl[0]).all()
               and _near(c2[r], t.snout_px[1], TOL * fl[1]).all()
               for r in rows):
        return "associated"
    return "filtered"


def located_why(t, tr: dict, min_conf: float, upright: bool = False) -> list[str]:
    """Why fish ``t`` (lost at ``located``) has no located fork within 3 %, per image lacking one
    (module docstring); the learned locator is asked again from the hypotheses near its fork."""
    out = []
    for c, (pyr, hyps) in enumerate(tr["hypotheses"]):
        fl = float(np.linalg.norm(t.snout_px[c] - t.fork_px[c]))
        if _near(tr["located"][c], t.fork_px[c], TOL * fl).any():
            continue
        near = np.flatnonzero(_near(hyps.xy, t.fork_px[c], PROPOSE_TOL * fl))
        nf = fork_net.locate(pyr, hyps.take(near), upright=upright)
        close = _near(nf.xy, t.fork_px[c], TOL * fl)
        sure = nf.confidence >= min_conf
        out.append("dropped" if (close & sure).any() else "unsure" if close.any() else
                   "misplaced" if sure.any() else "both")
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--params", default="", help="Params fields, e.g. 'outlines=False,min_score=0.12'")
    ap.add_argument("--conditions", default="{}", help='scene conditions as JSON, e.g. \'{"clutter": "reef"}\'')
    args = ap.parse_args()
    changes = {}
    # split at the commas that start another field (a tuple's own commas stay)
    for item in filter(None, re.split(r",(?=\s*\w+\s*=)", args.params)):
        key, value = item.split("=")
        changes[key.strip()] = ast.literal_eval(value.strip())
    params = dataclasses.replace(Params(), **changes)
    cv2.setNumThreads(1)
    setup = SurveySetup(up_world=(0.0, 0.0, 1.0))
    lost = {s: 0 for s in STAGES} | {"found": 0}
    visible = 0
    sized: list[tuple[float, str]] = []
    why: dict[str, int] = {}
    for seed in range(args.seed0, args.seed0 + args.scenes):
        sc = underwater_scene(np.random.default_rng(seed), **json.loads(args.conditions))
        tr: dict = {}
        fish = measure_underwater(sc.left, sc.right, sc.rig.calibration(), setup, params=params, trace=tr)
        hits = {ti for _, ti, _, _ in assign(fish, sc.fish, sc.rig.centres[0]) if ti >= 0}
        for i, t in enumerate(sc.fish):
            if t.fully_visible:
                visible += 1
                stage = fish_stage(t, tr, i in hits)
                lost[stage] += 1
                if stage == "located" and params.fork_net:
                    for w in located_why(t, tr, params.net_min_conf, params.upright):
                        why[w] = why.get(w, 0) + 1
                sized.append((float(np.linalg.norm(t.snout_px[0] - t.fork_px[0])), stage))
    passed, out = visible, {}
    for s in STAGES:
        passed -= lost[s]
        out[s] = {"lost": lost[s], "passed": passed}
    print(json.dumps({"scenes": args.scenes, "seed0": args.seed0, "params": changes,
                      "conditions": json.loads(args.conditions), "fully_visible": visible,
                      "stages": out,
                      "found": lost["found"], "by_length_px": _by_length(sized), "located_why": why}))


def _by_length(sized: list[tuple[float, str]]) -> list[dict]:
    """Where the fish of each third of the image lengths (left image) are lost."""
    px = np.array([p for p, _ in sized])
    edges = np.quantile(px, [0, 1 / 3, 2 / 3, 1]) if len(px) else np.zeros(4)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        stages = [s for p, s in sized if lo <= p <= hi]
        out.append({"from": round(float(lo), 1), "to": round(float(hi), 1), "fish": len(stages)}
                   | {s: stages.count(s) for s in (*STAGES, "found")})
    return out


if __name__ == "__main__":
    main()
