"""Training images for the full-image fish keypoint net (``vision.fish_keypoints``), from rendered
underwater pairs.

Run (the project's venv): ``.venv/bin/python tools/keynet_data.py --seed0 100000 --scenes 1200
--out /tmp/kn_a.npz [--species oreochromis_niloticus] [--conditions '{"clutter": "reef"}']``
(``--species``: every scene of that species; ``--conditions``: those scene conditions given).
Seeds must be >= 100000: the benches use 0+ and 1000+, and nothing is trained
or tuned on those. Deterministic for a seed range.

Per view (left and right) of each scene: the image at the net's stored size (``--width``, INTER_AREA,
as ``vision.fish_keypoints`` downscales), and per fish its snout and fork (in that image's px), the
share of it hidden in that view and whether it lies whole inside the frame. Training decides what
a target is (tools/train_keynet.py): the ends of clear fish are targets, those of partly hidden or
cut fish are masked out (whether their ends show is unknown).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from devices.sim.fish_scene import underwater_scene  # noqa: E402

FIRST_SEED = 100000
MAX_FISH = 24


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed0", type=int, default=FIRST_SEED)
    ap.add_argument("--scenes", type=int, default=1200)
    ap.add_argument("--width", type=int, default=384)
    ap.add_argument("--out", required=True)
    ap.add_argument("--species", help="every scene of this species (devices.sim.fish_species)")
    ap.add_argument("--conditions", default="{}",
                    help='scene conditions as JSON, e.g. \'{"clutter": "reef"}\' (the rest drawn)')
    args = ap.parse_args()
    if args.seed0 < FIRST_SEED:
        sys.exit(f"keynet_data: --seed0: {args.seed0} is below {FIRST_SEED} (the benches' seeds)")
    imgs, fish = [], []
    for seed in range(args.seed0, args.seed0 + args.scenes):
        given = json.loads(args.conditions) | ({"species": args.species} if args.species else {})
        sc = underwater_scene(np.random.default_rng(seed), **given)
        for c, img in enumerate((sc.left, sc.right)):
            H, W = img.shape[:2]
            s = args.width / W
            small = cv2.resize(img, (args.width, round(H * s)), interpolation=cv2.INTER_AREA)
            # (snout x, y, fork x, y, hidden share, whole fish in frame, fully visible), px of `small`
            rows = np.full((MAX_FISH, 7), np.nan, np.float32)
            for k, f in enumerate(sc.fish[:MAX_FISH]):
                sn, fk = f.snout_px[c], f.fork_px[c]
                inside = all(0 <= p[0] < W and 0 <= p[1] < H for p in (sn, fk))
                rows[k] = [(sn[0] + 0.5) * s - 0.5, (sn[1] + 0.5) * s - 0.5, (fk[0] + 0.5) * s - 0.5,
                           (fk[1] + 0.5) * s - 0.5, f.hidden[c], inside, f.fully_visible]
            imgs.append(small)
            fish.append(rows)
        if (seed - args.seed0) % 100 == 99:
            print(f"{seed - args.seed0 + 1} scenes", flush=True)
    np.savez(args.out, x=np.stack(imgs), fish=np.stack(fish),
             seed=np.repeat(np.arange(args.seed0, args.seed0 + args.scenes), 2))


if __name__ == "__main__":
    main()
