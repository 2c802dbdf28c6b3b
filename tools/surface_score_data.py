"""Reports of the surface setup on rendered tanks, labelled right or wrong by the bench's rule, for
fitting ``vision.surface_score`` (``tools/fit_score.py --setup surface``).

Run: ``.venv/bin/python tools/surface_score_data.py --seed0 8000 --scenes 100 --out /tmp/surface_a.npz``
(~0.1 s a tank on one core). Every paired fish is taken, before the reporting cut, so that the wrong
reports it would drop are in the data too. Keep these seeds apart from the bench's (1000, 5000) and
the tuning seeds (7000+). Rows as ``tools/score_data.py`` writes them (one per report): seed,
matched fish (-1: none), right (0/1), the fish fully visible (0/1), the hand-made score, placement
error, length error, length (cm), then every figure of ``FishMeasurement.quality``.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench.bench_survey_surface import _match  # noqa: E402
from devices.sim.fish_scene import surface_scene  # noqa: E402
from devices.sim.fish_species import SPECIES  # noqa: E402
from tools.score_data import HEAD  # noqa: E402
from vision.surface import surface_stages  # noqa: E402
from vision.survey_types import FishGeometry, SurveySetup  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed0", type=int, required=True)
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    rows, keys, visible = [], None, 0
    for seed in range(args.seed0, args.seed0 + args.scenes):
        sc = surface_scene(np.random.default_rng(seed))
        sp = SPECIES[sc.conditions["species"]]
        setup = SurveySetup(setup="surface", up_world=(0.0, 0.0, 1.0),
                            geometry=FishGeometry(fin_base_to_fork=sp.body_end))
        found = surface_stages(sc.left, sc.right, sc.rig.calibration(), setup)["measured"]
        visible += sum(t.fully_visible for t in sc.fish)
        hit: set[int] = set()
        for m in sorted(found, key=lambda m: -m.quality["hand_score"]):
            i, kind, err = _match(m, sc.fish, sc.rig.centres[0])
            right = kind == "ok" and i not in hit       # a fish reported twice: right once
            if right:
                hit.add(i)
            t = sc.fish[i] if i is not None else None
            keys = keys or sorted(m.quality)
            rows.append([seed, -1 if i is None else i, int(right), int(t is not None and t.fully_visible),
                         m.quality["hand_score"], err,
                         np.nan if t is None else m.length_cm / t.length_cm - 1, m.length_cm]
                        + [m.quality[k] for k in keys])
    np.savez(args.out, rows=np.array(rows, float).reshape(len(rows), -1), keys=np.array(HEAD + (keys or [])),
             fully_visible=visible, params="surface")
    print(args.out, len(rows), "reports,", visible, "fully visible fish")


if __name__ == "__main__":
    main()
