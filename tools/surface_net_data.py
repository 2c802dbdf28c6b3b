"""Training crops for the surface setup's learned end locators (``vision.surface_nets``: the fork
locator's net, ``vision.fork_net``, trained on fish seen from above), from rendered nursery tanks.

Run (the project's venv): ``.venv/bin/python tools/surface_net_data.py --seed0 120000 --scenes 400
--out /tmp/surf_a`` writes ``/tmp/surf_a_snout.npz`` and ``/tmp/surf_a_base.npz``. Seeds must be
>= 100000 (the benches use 1000+, 5000+, 7000+ and the score 8000+). Deterministic for a seed range.

Two ends, each in the crop's frame the locators use (``u`` into the body, the crop reaching
``-fork_net.U0`` spans out past the end and ``fork_net.U1`` into the body, a span ``SPAN_OF_FL`` x
the fork length):
- ``snout``: the snout tip, the axis from it into the body;
- ``base``: the body's rear end, the caudal fin's base (the renderer's ``body_end`` x the fork
  length from the snout: what the survey places the fork from, by the species' ratio, when the
  notch is not seen, as from above it seldom is), the axis from it towards the head.
Per view of each scene, crops of:
- the survey's own ends (``vision.surface.detect_fish``: every region's snout and body end with
  its axis and length): the distribution the nets meet; those near no clear end are negatives;
- jittered hypotheses round each clear fish's true end: up to 0.3 of the length into the body and
  0.1 out past it (the regions' ends fall short by up to a quarter of the length on pale heads and
  thin peduncles), +-0.05 across, the axis turned by up to +-15 degrees, the span x exp(+-0.25);
- as many fine ones, as the locator's last pass sees the end (span x 0.4..0.85, -0.03..0.05 of
  the length along, +-0.02 across, the axis within +-8 degrees);
- hard negatives (``fork_net_data.hard_negatives``: the end seen from behind, the other end, the
  middle) and random points.
Labels as ``fork_net_data.labels``: positive when a clear fish (< 25 % hidden in that view, inside
the image) has that end in the crop with its axis within 40 degrees and a fitting span; the target
is the end (u, v in spans) and the axis' turn. Crops with the end of a partly hidden fish in them
are left out.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from devices.sim.fish_scene import surface_scene  # noqa: E402
from devices.sim.fish_species import SPECIES  # noqa: E402
from tools.fork_net_data import CLEAR, FIRST_SEED, Crops, finer, hard_negatives, labels  # noqa: E402
from tools.snout_net_data import jittered  # noqa: E402
from vision import surface, surface_nets  # noqa: E402
from vision.fins import Fins  # noqa: E402
from vision.fork import pyramid  # noqa: E402

ENDS = ("snout", "base")


def true_ends(sc, c: int, shape):
    """Per fish in view ``c``: snout and body end (N, 2 each), the fork length (N,) and which are
    clear (inside the image by 2 px, under CLEAR hidden, over 16 px long)."""
    ratio = np.array([SPECIES[f.species].body_end for f in sc.fish])
    snout = np.array([f.snout_px[c] for f in sc.fish]).reshape(-1, 2)
    fork = np.array([f.fork_px[c] for f in sc.fish]).reshape(-1, 2)
    base = snout + ratio[:, None] * (fork - snout)
    length = np.hypot(*(fork - snout).T)
    H, W = shape[:2]
    inside = np.all((np.minimum(snout, fork) > 2) & (np.maximum(snout, fork) < [W - 3, H - 3]), axis=1)
    clear = np.array([f.hidden[c] < CLEAR for f in sc.fish], bool) & inside & (length > 16)
    return snout, base, length, clear


def paint_fins(rng, img: np.ndarray, sc, c: int) -> np.ndarray:
    """``img`` with each fish's caudal fin drawn as seen edge-on from above: a line (or a narrow V of
    the two lobes) from the fin's base to the lobes' tips, 0.7-3 px wide, darkening the floor by
    5-60 %. The renderer's fins are thin planes: from above they show as a pale, narrow V where the
    fish rolls or pitches and all but vanish where it swims level. A darker fin line (the tests'
    drawn fish, an outside tester's renders; a real fin bends and shows) a locator trained without
    it took for body: its base on the fin, the fork 10-19 % of the length long."""
    H, W = img.shape[:2]
    shade = np.zeros((H, W), np.float32)
    for f in sc.fish:
        sp = SPECIES[f.species]
        snout, fork = np.asarray(f.snout_px[c], float), np.asarray(f.fork_px[c], float)
        axis = fork - snout
        length = float(np.hypot(*axis))
        if length < 8:
            continue
        e = axis / length
        n = np.array([-e[1], e[0]])
        base = snout + sp.body_end * axis
        tip = snout + sp.lobe_tip * rng.uniform(0.95, 1.08) * axis
        spread = rng.uniform(0.0, 0.04) * length if rng.random() < 0.5 else 0.0
        width = rng.uniform(0.7, 3.0)
        mask = np.zeros((H, W), np.float32)
        for side in ((0.0,) if spread == 0 else (-1.0, 1.0)):
            a, b = base, tip + side * spread * n
            cv2.line(mask, tuple(np.round(a * 16).astype(int)), tuple(np.round(b * 16).astype(int)), 1.0,
                     max(1, int(round(width))), cv2.LINE_AA, 4)
        shade = np.maximum(shade, mask * min(width, 1.0) * rng.uniform(0.05, 0.6))
    shade = cv2.GaussianBlur(shade, (0, 0), 0.6)
    out = img.astype(np.float32) * (1.0 - (shade[..., None] if img.ndim == 3 else shade))
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def own_ends(fish, end: str) -> Fins:
    """The survey's own hypotheses for one end, as ``vision.surface_nets`` makes them."""
    if not fish:
        return Fins.empty()
    at = surface_nets.hypotheses(*(np.array([getattr(f, k) for f in fish], float)
                                   for k in ("snout", "base", "fork", "length_px")))
    return at[ENDS.index(end)]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed0", type=int, default=120000)
    ap.add_argument("--scenes", type=int, default=400)
    ap.add_argument("--jitter", type=int, default=4)
    ap.add_argument("--out", required=True, help="prefix: PREFIX_snout.npz and PREFIX_base.npz are written")
    ap.add_argument("--conditions", default="{}", help="scene conditions as JSON (the rest drawn)")
    ap.add_argument("--fins", type=float, default=0.5, help="share of scenes whose caudal fins are painted "
                                                            "as seen from above (paint_fins)")
    args = ap.parse_args()
    if args.seed0 < FIRST_SEED:
        sys.exit(f"surface_net_data: --seed0: {args.seed0} is below {FIRST_SEED} (the benches' seeds)")
    rng = np.random.default_rng(args.seed0)
    surface.LEARNED_ENDS = False       # the hypotheses: the regions' own ends, as the nets meet them
    out = {end: Crops() for end in ENDS}
    for seed in range(args.seed0, args.seed0 + args.scenes):
        sc = surface_scene(np.random.default_rng(seed), **json.loads(args.conditions))
        ratio = SPECIES[sc.conditions["species"]].body_end
        fins = rng.random() < args.fins
        for c, img in enumerate((sc.left, sc.right)):
            if fins:
                img = paint_fins(rng, img, sc, c)
            pyr = pyramid(img)
            found = surface.detect_fish(img, base_ratio=ratio)
            snout, base, length, clear = true_ends(sc, c, img.shape)
            good = np.flatnonzero(clear)
            for end, here, there in (("snout", snout, base), ("base", base, snout)):
                d = there - here
                axis = np.arctan2(d[:, 1], d[:, 0])
                negatives = hard_negatives(rng, here[good], there[good], axis[good], length[good], img.shape)
                parts = [(0, own_ends(found, end)),
                         # regions' ends fall short by up to a quarter of the length (pale heads,
                         # thin peduncles): up to 0.3 of it into the body, 0.1 out past the end
                         (1, jittered(rng, here[good], axis[good], length[good], args.jitter,
                                      along=(-0.1, 0.3), across=0.05)),
                         (1, jittered(rng, here[good], axis[good], length[good], args.jitter, fine=True)),
                         (2, negatives), (2, finer(rng, negatives))]
                for src, h in parts:
                    keep, pos, u, v, t, rel = labels(h, here, axis, length, clear, max_scale=2.6)
                    out[end].add(pyr, h, keep, (pos, u, v, t, rel), (seed, c, src))
        out["base"].progress(seed - args.seed0 + 1)
    for end in ENDS:
        out[end].save(f"{args.out}_{end}.npz")


if __name__ == "__main__":
    main()
