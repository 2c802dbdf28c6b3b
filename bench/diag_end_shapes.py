"""The learned end locators (``vision.snout_net``, ``vision.fork_net``) started round each true end,
by the shape of the fish's head and fork: does a tip stay a tip whatever the snout looks like?

Per set, from jittered starts round every clearly visible fish's true snout (-0.03..0.08 of its
length into the body, +-0.03 across) and fork (0.03..0.15 ahead of it, +-0.05 across, the axis
within +-10 degrees): each answer's error along the true axis in % of the length (+: outward, the
snout ahead of the true tip or the fork behind the true notch; a negative sum reads fish short), its
median and the share within 1 %, for the answers the net is at least 0.5 sure of. Sets:
- ``ours:T``: the project's renderer (seeds 200000+) with every fish's ``snout_taper`` T (the head's
  outline as u^(0.66 + T); 0 is the species' own), ``ours:T:N`` also its ``notch_power`` N;
- ``drawn:P``: tests/vision/fish_drawing's 2-D fish with snouts of power P (0.5 an ellipse's head),
  snouts only;
- ``outside_fish`` / ``outside_fish2``: the outside testers' renderers (their own seeds 60 / 70).

Run: ``.venv/bin/python bench/diag_end_shapes.py [--scenes 30] [--sets ours:0,ours:0.5,drawn:1.2,outside_fish2]``.
Prints one JSON object (2026-12-06: README, "Snout shapes").
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tests.vision.fish_drawing import fish_scene_2d  # noqa: E402
from tools.fork_net_data import ends  # noqa: E402
from vision import fork_net, snout_net  # noqa: E402
from vision.fins import SPAN_OF_FL, Fins  # noqa: E402
from vision.fork import pyramid  # noqa: E402

K = 3      # starts an end


def snout_errors(rng, pyr, snouts, forks):
    """(error % of the length, confidence) of the snout net from K starts round each snout."""
    d = forks - snouts
    L = np.hypot(d[:, 0], d[:, 1])
    ax, nrm = d / L[:, None], np.c_[-d[:, 1], d[:, 0]] / L[:, None]
    off = rng.uniform(-0.03, 0.08, (len(L), K)) * L[:, None]
    across = rng.uniform(-0.03, 0.03, (len(L), K)) * L[:, None]
    starts = snouts[:, None] + off[..., None] * ax[:, None] + across[..., None] * nrm[:, None]
    tips, conf = snout_net.refine(pyr, forks, starts)
    return (-np.einsum("nkd,nd->nk", tips - snouts[:, None], ax) / L[:, None] * 100).ravel(), conf.ravel()


def fork_errors(rng, pyr, snouts, forks):
    """(error % of the length, confidence) of the fork net from K starts round each fork."""
    d = snouts - forks
    L = np.hypot(d[:, 0], d[:, 1])
    k = np.repeat(np.arange(len(L)), K)
    ax, nrm = d[k] / L[k, None], np.c_[-d[k, 1], d[k, 0]] / L[k, None]
    xy = forks[k] + (rng.uniform(0.03, 0.15, len(k)) * L[k])[:, None] * ax \
        + (rng.uniform(-0.05, 0.05, len(k)) * L[k])[:, None] * nrm
    angle = np.arctan2(ax[:, 1], ax[:, 0]) + np.radians(rng.uniform(-10, 10, len(k)))
    z = np.zeros(len(k))
    located = fork_net.locate(pyr, Fins(xy, angle, SPAN_OF_FL * L[k], z, z.copy()))
    return -np.einsum("nd,nd->n", located.xy - forks[k], ax) / L[k] * 100, located.confidence


def views(name: str, scenes: int, rng):
    """(image, snouts (n, 2), forks (n, 2)) of every view of a set's scenes."""
    kind, *args = name.split(":")
    if kind == "ours":
        from devices.sim.fish_scene import underwater_scene
        given = {"snout_taper": [float(args[0])] * 2}
        if len(args) > 1:
            given["notch_power"] = [float(args[1])] * 2
        for seed in range(200000, 200000 + scenes):
            sc = underwater_scene(np.random.default_rng(seed), **given)
            for c, img in enumerate((sc.left, sc.right)):
                s, f, _, _, clear = ends(sc.fish, c, img.shape, "snout")
                yield img, s[clear], f[clear]
    elif kind == "drawn":
        for _ in range(scenes):
            img, forks, snouts = fish_scene_2d(rng, snout_power=float(args[0]))
            yield img, snouts, forks
    else:
        renderer = importlib.import_module(f"bench.{kind}")
        rig, own = renderer.make_rig(), np.random.default_rng({"outside_fish": 60}.get(kind, 70))
        for i in range(scenes):
            left, right, truth = renderer.render_pair(rig, own, i)
            fish = [t for t in truth["fish"] if t["visible"]]
            for c, img in enumerate((left, right)):
                yield (img, np.array([t["snout_px"][c] for t in fish]).reshape(-1, 2),
                       np.array([t["fork_px"][c] for t in fish]).reshape(-1, 2))


def summary(err, conf) -> dict:
    sure = np.asarray(err)[np.asarray(conf) >= 0.5]
    if len(sure) == 0:
        return {"n": 0}
    return {"n": int(len(sure)), "median_pct": round(float(np.median(sure)), 2),
            "within_1pct": round(float(np.mean(np.abs(sure) <= 1.0)), 3)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=30)
    ap.add_argument("--sets", default="ours:0,ours:-0.3,ours:0.5,ours:0:1.0,drawn:0.5,drawn:0.9,drawn:1.2,"
                                      "outside_fish,outside_fish2")
    args = ap.parse_args()
    out = {}
    for name in args.sets.split(","):
        rng = np.random.default_rng(5)
        acc = {"snout": ([], []), "fork": ([], [])}
        for img, snouts, forks in views(name, args.scenes, rng):
            if len(snouts) == 0:
                continue
            pyr = pyramid(img)
            for end, errors in (("snout", snout_errors), ("fork", fork_errors)):
                if end == "fork" and name.startswith("drawn"):
                    continue
                e, c = errors(rng, pyr, snouts, forks)
                acc[end][0].append(e)
                acc[end][1].append(c)
        out[name] = {end: summary(np.concatenate(e), np.concatenate(c)) for end, (e, c) in acc.items() if e}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
