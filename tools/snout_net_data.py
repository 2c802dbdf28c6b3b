"""Training crops for the learned snout locator (``vision.fork_net``'s net, trained on snouts:
``vision/models/snout_net.onnx``), from rendered underwater pairs.

Run (the project's venv): ``.venv/bin/python tools/snout_net_data.py --seed0 102000 --scenes 600
--out /tmp/snouts.npz [--conditions '{"snout_taper": [-0.3, 0.7]}']`` (``--conditions``: scene
conditions fixed, the rest drawn). Seeds must be >= 100000 (the benches use 0+ and 1000+). Deterministic for
a seed range.

The fork locator's crop seen from the other end: a hypothesis is a point near a snout, its axis
pointing into the body (towards the fork) and a span of ``SPAN_OF_FL`` x the length, so the crop
reaches well ahead of the snout into the water and back over the head. Per view of each scene:
- jittered hypotheses round each clearly visible fish's true snout (as the survey's snout
  candidates are off: -0.06..0.12 of the length along the axis, +-0.06 across, the axis turned by
  up to +-15 degrees, the span x exp(+-0.25));
- as many fine ones, as the locator's last pass sees the snout (``vision.snout_net.FINE``): the
  span x 0.4..0.85, -0.03..0.05 of the length along, +-0.02 across, the axis within +-8 degrees;
- hard negatives (``fork_net_data.hard_negatives`` with the ends swapped: the tail end, the fish's
  middle, the head seen from behind) and random points.
Labels as ``fork_net_data.labels`` with snouts for forks: the target is the snout (u, v in spans)
and the axis' turn; crops with the snout of a partly hidden fish in them are left out.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from devices.sim.fish_scene import underwater_scene  # noqa: E402
from tools.fork_net_data import FINE_SPANS, FIRST_SEED, Crops, ends, finer, hard_negatives, labels  # noqa: E402
from vision.fins import SPAN_OF_FL, Fins, down_side  # noqa: E402
from vision.fork import pyramid  # noqa: E402


def jittered(rng, snouts, axis, length, n, fine: bool = False, along=(-0.06, 0.12), across=0.06):
    """n hypotheses round each snout (``axis``: from the snout into the body), ``along`` (into the
    body) and ``across`` it in lengths; ``fine``: the last pass's, nearer and at a finer span."""
    S = len(snouts)
    if S == 0:
        return Fins.empty()
    k = np.repeat(np.arange(S), n)
    L = length[k]
    a = np.c_[np.cos(axis[k]), np.sin(axis[k])]
    nrm = np.c_[-a[:, 1], a[:, 0]]
    along, across, turn, scale = ((-0.03, 0.05), 0.02, 8, tuple(np.log(FINE_SPANS))) if fine else \
        (along, across, 15, (-0.25, 0.25))
    xy = (snouts[k] + (rng.uniform(*along, len(k)) * L)[:, None] * a
          + (rng.uniform(-across, across, len(k)) * L)[:, None] * nrm)
    ang = axis[k] + np.radians(rng.uniform(-turn, turn, len(k)))
    span = SPAN_OF_FL * L * np.exp(rng.uniform(*scale, len(k)))
    z = np.zeros(len(k))
    return Fins(xy, ang, span, z, z.copy())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed0", type=int, default=102000)
    ap.add_argument("--scenes", type=int, default=600)
    ap.add_argument("--jitter", type=int, default=6)
    ap.add_argument("--out", required=True)
    ap.add_argument("--conditions", default="{}",
                    help='scene conditions as JSON, e.g. \'{"snout_taper": [-0.3, 0.7]}\' (the rest drawn)')
    ap.add_argument("--upright", action="store_true",
                    help="crops upright (vision.fins.down_side of the fish's heading), as the survey's "
                         "Params.upright_snouts samples them; train them with train_fork_net.py --no-flip")
    args = ap.parse_args()
    if args.seed0 < FIRST_SEED:
        sys.exit(f"snout_net_data: --seed0: {args.seed0} is below {FIRST_SEED} (the benches' seeds)")
    rng = np.random.default_rng(args.seed0)
    out = Crops()
    for seed in range(args.seed0, args.seed0 + args.scenes):
        sc = underwater_scene(np.random.default_rng(seed), **json.loads(args.conditions))
        for c, img in enumerate((sc.left, sc.right)):
            pyr = pyramid(img)
            snouts, forks, axis, length, clear = ends(sc.fish, c, img.shape, "snout")
            good = np.flatnonzero(clear)
            negatives = hard_negatives(rng, snouts[good], forks[good], axis[good], length[good], img.shape)
            fine_negatives = finer(rng, negatives)
            for src, h in ((1, jittered(rng, snouts[good], axis[good], length[good], args.jitter)),
                           (1, jittered(rng, snouts[good], axis[good], length[good], args.jitter, fine=True)),
                           (2, negatives), (2, fine_negatives)):
                keep, pos, u, v, t, rel = labels(h, snouts, axis, length, clear, max_scale=2.6)
                # upright: the handedness vision.snout_net.refine gives the crop in the survey
                out.add(pyr, h, keep, (pos, u, v, t, rel), (seed, c, src),
                        -down_side(h.angle) if args.upright else None)
        out.progress(seed - args.seed0 + 1)
    out.save(args.out)


if __name__ == "__main__":
    main()
