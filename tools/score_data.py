"""Reports of the underwater survey on rendered scenes, labelled right or wrong by the bench's
rule, for fitting ``vision.learned_score`` (tools/fit_score.py).

Run: ``.venv/bin/python tools/score_data.py --seed0 300000 --scenes 250 --out /tmp/score_a.npz``
(~1 s a scene on one core). The pipeline runs with its post-filters off (``min_score=0``,
``max_epipolar=1e9``, the learned score off) so that the wrong reports they would drop are in the
data too; ``--params`` changes further ``vision.underwater.Params`` fields. Keep these seeds apart
from the benches' (0+, 1000+) and the tuning seeds (200000+).

Writes rows (one per report) of: seed, matched fish (-1: none), right (0/1), the fish fully visible
(0/1), the hand-made score, placement error, length error, length (cm), then every figure of
``FishMeasurement.quality``; ``keys`` names the columns, ``fully_visible`` counts the scenes' fully
visible fish (recall's denominator).
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
from bench.bench_survey_underwater import assign, parse_params  # noqa: E402
from devices.sim.fish_scene import underwater_scene  # noqa: E402
from vision.survey_types import SurveySetup  # noqa: E402
from vision.underwater import measure_underwater  # noqa: E402

HEAD = ["seed", "fish", "right", "visible", "score", "placement_err", "length_err", "length_cm"]
UNFILTERED = "min_score=0.0,max_epipolar=1e9,learned_score=False"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed0", type=int, required=True)
    ap.add_argument("--scenes", type=int, default=250)
    ap.add_argument("--out", required=True)
    ap.add_argument("--params", default="", help="further Params fields, e.g. 'fork_net=False'")
    args = ap.parse_args()
    params = parse_params(",".join(filter(None, [UNFILTERED, args.params])))
    cv2.setNumThreads(1)
    setup = SurveySetup(up_world=(0.0, 0.0, 1.0))
    rows, keys, visible_total = [], None, 0
    for seed in range(args.seed0, args.seed0 + args.scenes):
        sc = underwater_scene(np.random.default_rng(seed))
        fish = measure_underwater(sc.left, sc.right, sc.rig.calibration(), setup, params=params)
        visible = {i for i, t in enumerate(sc.fish) if t.fully_visible}
        visible_total += len(visible)
        for k, ti, err, len_err in assign(fish, sc.fish, sc.rig.centres[0]):
            q = fish[k].quality
            keys = keys or sorted(q)
            rows.append([seed, ti, int(ti >= 0), int(ti in visible), fish[k].score, err, len_err, fish[k].length_cm]
                        + [q[x] for x in keys])
    np.savez(args.out, rows=np.array(rows, float).reshape(len(rows), -1), keys=np.array(HEAD + (keys or [])),
             fully_visible=visible_total, params=args.params)
    print(args.out, len(rows), "reports,", visible_total, "fully visible fish")


if __name__ == "__main__":
    main()
