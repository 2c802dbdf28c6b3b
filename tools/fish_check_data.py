"""Training crops for the whole-report check (``vision.fish_check``), from rendered underwater pairs.

Run (the project's venv): ``.venv/bin/python tools/fish_check_data.py --seed0 310000 --scenes 400
--out /tmp/fc_a.npz`` (~1 s a scene on one core). Seeds must be >= 100000 and apart from the score's
(300000+) and the tuning seeds (200000+).

Per view of each scene, segments (a fork point, a snout point), each labelled right when both lie
within 3 % of the length of one fish's own ends in that image:
- round each clear fish's true ends, each end jittered within 1.5 % of the length (right);
- the same fish with one end moved 4-15 % along the body or 4-12 % across it, and its fork with
  another fish's snout (mostly wrong: the label is the rule's, not the move's);
- every report of the survey's pipeline with its post-filters off (the segments it really makes,
  right and wrong), but for those on partly hidden fish (the rule cannot say).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench.bench_survey_underwater import parse_params  # noqa: E402
from devices.sim.fish_scene import underwater_scene  # noqa: E402
from tools.fork_net_data import CLEAR, FIRST_SEED  # noqa: E402
from vision import fish_check  # noqa: E402
from vision.fork import pyramid  # noqa: E402
from vision.survey_types import SurveySetup  # noqa: E402
from vision.underwater import measure_underwater  # noqa: E402

TOL = 0.03
UNFILTERED = "min_score=0.0,max_epipolar=1e9,learned_score=False"


def label(fork: np.ndarray, snout: np.ndarray, forks: np.ndarray, snouts: np.ndarray, clear: np.ndarray):
    """(N,) 1 right, 0 wrong, -1 unsure (right but for a partly hidden fish)."""
    L = np.linalg.norm(snouts - forks, axis=1)                                       # (F,)
    ok = ((np.linalg.norm(fork[:, None] - forks[None], axis=2) <= TOL * L)
          & (np.linalg.norm(snout[:, None] - snouts[None], axis=2) <= TOL * L))     # (N, F)
    return np.where((ok & clear).any(axis=1), 1, np.where(ok.any(axis=1), -1, 0))


def synthetic(rng, forks, snouts, clear):
    """Segments round the clear fish: jittered (3 each), moved ends (4 each), mixed fish (1 each)."""
    good = np.flatnonzero(clear)
    f_out, s_out = [], []
    for i in good:
        f, s = forks[i], snouts[i]
        L = np.linalg.norm(s - f)
        a = (s - f) / L
        n = np.array([-a[1], a[0]])
        for _ in range(3):
            f_out.append(f + rng.uniform(-0.015, 0.015, 2) * L)
            s_out.append(s + rng.uniform(-0.015, 0.015, 2) * L)
        for end in (0, 1):
            for move in ("along", "across"):
                d = rng.uniform(0.04, 0.15 if move == "along" else 0.12) * L * rng.choice([-1, 1])
                step = d * (a if move == "along" else n)
                f_out.append(f + step if end == 0 else f.copy())
                s_out.append(s + step if end == 1 else s.copy())
        others = good[good != i]
        if len(others):
            j = others[np.argmin(np.linalg.norm(snouts[others] - s, axis=1))]
            f_out.append(f.copy())
            s_out.append(snouts[j].copy())
    return np.array(f_out).reshape(-1, 2), np.array(s_out).reshape(-1, 2)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed0", type=int, default=310000)
    ap.add_argument("--scenes", type=int, default=400)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    if args.seed0 < FIRST_SEED:
        sys.exit(f"fish_check_data: --seed0: {args.seed0} is below {FIRST_SEED} (the benches' seeds)")
    rng = np.random.default_rng(args.seed0)
    params = parse_params(UNFILTERED)
    setup = SurveySetup(up_world=(0.0, 0.0, 1.0))
    xs, ys, meta = [], [], []
    for seed in range(args.seed0, args.seed0 + args.scenes):
        sc = underwater_scene(np.random.default_rng(seed))
        reports = measure_underwater(sc.left, sc.right, sc.rig.calibration(), setup, params=params)
        for c, img in enumerate((sc.left, sc.right)):
            pyr = pyramid(img)
            forks = np.array([t.fork_px[c] for t in sc.fish]).reshape(-1, 2)
            snouts = np.array([t.snout_px[c] for t in sc.fish]).reshape(-1, 2)
            H, W = img.shape[:2]
            inside = np.all((forks > 2) & (forks < [W - 3, H - 3]) & (snouts > 2) & (snouts < [W - 3, H - 3]), axis=1)
            clear = np.array([t.hidden[c] < CLEAR for t in sc.fish], bool) & inside \
                & (np.linalg.norm(snouts - forks, axis=1) > 20)
            sf, ss = synthetic(rng, forks, snouts, clear)
            pf = np.array([r.fork_px[c] for r in reports]).reshape(-1, 2)
            ps = np.array([r.snout_px[c] for r in reports]).reshape(-1, 2)
            for source, f, s in ((0, sf, ss), (1, pf, ps)):
                if len(f) == 0:
                    continue
                y = label(f, s, forks, snouts, clear) if len(forks) else np.zeros(len(f), int)
                keep = y >= 0
                xs.append(fish_check.raw_crops(pyr, f[keep], s[keep]))
                ys.append(y[keep])
                meta.append(np.column_stack([np.full(keep.sum(), seed), np.full(keep.sum(), c),
                                             np.full(keep.sum(), source)]))
    x, y, m = np.concatenate(xs), np.concatenate(ys), np.concatenate(meta)
    np.savez_compressed(args.out, x=x, y=y, meta=m)
    print(f"{args.out}: {len(y)} crops, {int(y.sum())} right; from the pipeline {int((m[:, 2] == 1).sum())} "
          f"({int(y[m[:, 2] == 1].sum())} right)")


if __name__ == "__main__":
    main()
