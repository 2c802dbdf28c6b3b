"""Training crops for the learned fork locator (``vision.fork_net``), from rendered underwater pairs.

Run (the project's venv): ``.venv/bin/python tools/fork_net_data.py --seed0 100000 --scenes 1500
--out /tmp/forks.npz [--conditions '{"clutter": "rock"}']`` (``--conditions``: those scene conditions
given, the rest drawn). Seeds must be >= 100000: the benches use 0+ and 1000+, and nothing is trained
or tuned on those. Deterministic for a seed range (the jitter's generator is seeded from it).

Per view of each scene, crops (``fork_net.raw_crops``) of:
- the pipeline's own fork hypotheses (``vision.underwater.proposals``): the distribution the net
  meets in the survey; every one near a true fork, a share (``--neg-share``) of the others;
- jittered hypotheses round each clearly visible fish's true fork: ahead of it by -0.05..0.35 of
  its length along its axis and +-0.1 across, span 0.3 of the length x exp(+-0.29) (the proposals'
  errors, vision/bodies.py), axis turned by up to +-25 degrees;
- hard negatives: the same fish's fork with the axis reversed (the fin seen from behind), its
  snout end, its middle; and random points, axes and spans.
Label: a crop is positive when a clearly visible fish (< 25 % hidden in that view) has its fork
inside the crop (0.08 span from its edges), its axis within 40 degrees of the crop's and a span
0.6-1.7x the crop's; the target is that fork (u, v in spans) and the axis' turn. Crops with the
fork of a partly hidden fish in them are left out (whether its fork shows is unknown).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from devices.sim.fish_scene import underwater_rig, underwater_scene  # noqa: E402
from vision import fork_net  # noqa: E402
from vision.fins import SPAN_OF_FL, Fins  # noqa: E402
from vision.survey_types import SurveySetup  # noqa: E402
from vision.underwater import proposals  # noqa: E402

FIRST_SEED = 100000
CLEAR = 0.25            # hidden share under which a fish's fork is taken as visible
MARGIN = 0.08           # spans inside the crop's edges


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def labels(h: Fins, forks: np.ndarray, axis: np.ndarray, length: np.ndarray, clear: np.ndarray,
           max_scale: float = 1.7):
    """Per hypothesis: (keep, positive, u, v, turn, length / span); a positive's span is within
    0.6 .. ``max_scale`` of SPAN_OF_FL x its fish's length."""
    N = len(h)
    keep, pos = np.ones(N, bool), np.zeros(N, bool)
    u, v, turn, rel = np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N)
    if len(forks) == 0:
        return keep, pos, u, v, turn, rel
    a = np.c_[np.cos(h.angle), np.sin(h.angle)]
    d = forks[None] - h.xy[:, None]                                            # (N, F, 2)
    du = (d[..., 0] * a[:, None, 0] + d[..., 1] * a[:, None, 1]) / h.span_px[:, None]
    dv = (-d[..., 0] * a[:, None, 1] + d[..., 1] * a[:, None, 0]) / h.span_px[:, None]
    inside = (du > fork_net.U0 + MARGIN) & (du < fork_net.U1 - MARGIN) & (np.abs(dv) < fork_net.V1 - MARGIN)
    dt = _wrap(axis[None] - h.angle[:, None])
    scale = SPAN_OF_FL * length[None] / h.span_px[:, None]
    fits = inside & (np.abs(dt) < np.radians(40)) & (scale > 0.6) & (scale < max_scale)
    keep = ~(inside & ~clear[None]).any(axis=1)
    dist = np.where(fits & clear[None], np.hypot(du + 0.3, dv), np.inf)
    best = dist.argmin(axis=1)
    pos = np.isfinite(dist[np.arange(N), best])
    r = np.arange(N)
    return keep, pos, du[r, best], dv[r, best], dt[r, best], (length[best] / h.span_px)


FINE_SPANS = (0.4, 0.85)     # the fine crops' spans, x the usual (about ``FINE`` of the locators)


def finer(rng, hyps: Fins) -> Fins:
    """A copy of ``hyps`` at a span drawn from ``FINE_SPANS`` x theirs: the fine pass's negatives."""
    out = hyps.take(np.arange(len(hyps)))
    out.span_px = out.span_px * rng.uniform(*FINE_SPANS, len(out))
    return out


def jittered(rng, forks, axis, length, n, fine: bool = False):
    """n hypotheses round each fork, as the proposals are off; ``fine``: as the locator's last pass
    starts (``vision.fork_net.FINE``: the span x 0.4..0.85, ``RECENTRE`` of it ahead of the fork,
    +-0.02 of the length along and across, the axis within +-8 degrees)."""
    F = len(forks)
    if F == 0:
        return Fins.empty()
    k = np.repeat(np.arange(F), n)
    L = length[k]
    a = np.c_[np.cos(axis[k]), np.sin(axis[k])]
    nrm = np.c_[-a[:, 1], a[:, 0]]
    if fine:
        span = SPAN_OF_FL * L * rng.uniform(*FINE_SPANS, len(k))
        ahead = fork_net.RECENTRE * span + rng.uniform(-0.02, 0.02, len(k)) * L
        xy = forks[k] + ahead[:, None] * a + (rng.uniform(-0.02, 0.02, len(k)) * L)[:, None] * nrm
        z = np.zeros(len(k))
        return Fins(xy, axis[k] + np.radians(rng.uniform(-8, 8, len(k))), span, z, z.copy())
    ang = axis[k] + np.radians(rng.uniform(-25, 25, len(k)))
    xy = (forks[k] + (rng.uniform(-0.05, 0.35, len(k)) * L)[:, None] * a
          + (rng.uniform(-0.1, 0.1, len(k)) * L)[:, None] * nrm)
    span = SPAN_OF_FL * L * np.exp(rng.uniform(-0.29, 0.22, len(k)))
    z = np.zeros(len(k))
    return Fins(xy, ang, span, z, z.copy())


def hard_negatives(rng, forks, snouts, axis, length, shape):
    F = len(forks)
    H, W = shape[:2]
    z = np.zeros
    parts = []
    if F:
        a = np.c_[np.cos(axis), np.sin(axis)]
        span = SPAN_OF_FL * length * np.exp(rng.uniform(-0.29, 0.22, F))
        back = forks - (rng.uniform(0.0, 0.3, F) * length)[:, None] * a        # fin seen from behind
        parts.append(Fins(back, axis + np.pi + np.radians(rng.uniform(-20, 20, F)), span, z(F), z(F)))
        snout = snouts + (rng.uniform(-0.05, 0.2, F) * length)[:, None] * a    # the head end
        parts.append(Fins(snout, axis + np.pi + np.radians(rng.uniform(-20, 20, F)), span, z(F), z(F)))
        mid = forks + (rng.uniform(0.35, 0.7, F) * length)[:, None] * a
        parts.append(Fins(mid, axis + rng.choice([0, np.pi], F), span, z(F), z(F)))
    R = 4
    parts.append(Fins(np.c_[rng.uniform(0, W, R), rng.uniform(0, H, R)], rng.uniform(-np.pi, np.pi, R),
                      rng.uniform(15, 150, R), z(R), z(R)))
    return Fins(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("xy", "angle", "span_px", "score",
                                                                              "polarity")))


def ends(fish, c: int, shape, end: str):
    """The rendered fish's ``end`` ("fork" or "snout") and other end in view ``c`` (N, 2 each), the
    axis from that end to the other (N,), the length (N,), and which are clear: inside the image by
    2 px, under CLEAR hidden there, over 20 px long."""
    here = np.array([getattr(f, f"{end}_px")[c] for f in fish]).reshape(-1, 2)
    there = np.array([f.snout_px[c] if end == "fork" else f.fork_px[c] for f in fish]).reshape(-1, 2)
    d = there - here
    axis, length = np.arctan2(d[:, 1], d[:, 0]), np.hypot(d[:, 0], d[:, 1])
    H, W = shape[:2]
    inside = (here[:, 0] > 2) & (here[:, 0] < W - 3) & (here[:, 1] > 2) & (here[:, 1] < H - 3)
    clear = np.array([f.hidden[c] < CLEAR for f in fish], bool) & inside & (length > 20)
    return here, there, axis, length, clear


class Crops:
    """The crops gathered so far, their labels (positive, u, v, turn, length / span) and where
    each came from (seed, view, source)."""

    def __init__(self):
        self.x, self.y, self.meta = [], [], []

    def add(self, pyr, h: Fins, keep: np.ndarray, label: tuple, where: tuple, side=None) -> None:
        """``side`` (N,): each crop's handedness (``fork_net.raw_crops``); v and the turn labels
        (``label``'s third and fourth) are in the axis' own frame and turn with it."""
        idx = np.flatnonzero(keep)
        if len(idx) == 0:
            return
        hand = np.ones(len(idx)) if side is None else np.asarray(side, float)[idx]
        self.x.append(fork_net.raw_crops(pyr, h.take(idx), hand))
        y = np.stack([np.asarray(a)[idx] for a in label], axis=1).astype(np.float32)
        y[:, 2:4] *= hand[:, None].astype(np.float32)
        self.y.append(y)
        self.meta.append(np.array([list(where)] * len(idx), np.int32))

    def progress(self, scenes: int) -> None:
        if scenes % 100 == 0:
            n, p = sum(len(y) for y in self.y), sum(int(y[:, 0].sum()) for y in self.y)
            print(f"{scenes} scenes, {n} crops, {p} positive", flush=True)

    def save(self, path: str) -> None:
        np.savez_compressed(path, x=np.concatenate(self.x), y=np.concatenate(self.y), meta=np.concatenate(self.meta))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed0", type=int, default=FIRST_SEED)
    ap.add_argument("--scenes", type=int, default=1500)
    ap.add_argument("--neg-share", type=float, default=0.15)
    ap.add_argument("--jitter", type=int, default=4)
    ap.add_argument("--size", default="1280x960", help="the rig's image size WxH (focal 1400 px at 1280 wide, "
                                                       "scaled with the width: smaller fish in smaller images)")
    ap.add_argument("--jpeg", type=int, default=None, help="each view through a JPEG round trip at this quality "
                                                           "(a streaming camera's)")
    ap.add_argument("--conditions", default="{}",
                    help='scene conditions as JSON, e.g. \'{"clutter": "cage"}\' (the rest drawn)')
    ap.add_argument("--fine", action="store_true",
                    help="crops at the locator's last pass' finer span too (vision.fork_net.FINE)")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    if args.seed0 < FIRST_SEED:
        sys.exit(f"fork_net_data: --seed0: {args.seed0} is below {FIRST_SEED} (the benches' seeds)")
    rng = np.random.default_rng(args.seed0)
    setup = SurveySetup(up_world=(0.0, 0.0, 1.0))
    w, h = (int(v) for v in args.size.lower().split("x"))
    rig = underwater_rig(image_size=(w, h), focal_px=1400.0 * w / 1280)
    out = Crops()
    for seed in range(args.seed0, args.seed0 + args.scenes):
        sc = underwater_scene(np.random.default_rng(seed), rig=rig, **json.loads(args.conditions))
        for c, img in enumerate((sc.left, sc.right)):
            if args.jpeg is not None:
                jpeg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, args.jpeg])[1]
                img = cv2.imdecode(jpeg, cv2.IMREAD_UNCHANGED)
            pyr, hyps = proposals(img, setup)[:2]
            forks, snouts, axis, length, clear = ends(sc.fish, c, img.shape, "fork")
            good = np.flatnonzero(clear)
            negatives = hard_negatives(rng, forks[good], snouts[good], axis[good], length[good], img.shape)
            parts = [(0, hyps), (1, jittered(rng, forks[good], axis[good], length[good], args.jitter)), (2, negatives)]
            if args.fine:
                fine_negatives = finer(rng, negatives)
                parts += [(1, jittered(rng, forks[good], axis[good], length[good], args.jitter, fine=True)),
                          (2, fine_negatives)]
            for src, h in parts:
                keep, pos, u, v, t, rel = labels(h, forks, axis, length, clear, max_scale=2.6 if args.fine else 1.7)
                if src == 0:
                    keep &= pos | (rng.random(len(h)) < args.neg_share)
                out.add(pyr, h, keep, (pos, u, v, t, rel), (seed, c, src))
        out.progress(seed - args.seed0 + 1)
    out.save(args.out)


if __name__ == "__main__":
    main()
