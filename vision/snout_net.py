"""A learned snout locator: the fork locator's net (``vision.fork_net``: a crop along a hypothesis'
axis, a heatmap's soft-argmax and a confidence) trained on snouts instead of forks
(``vision/models/snout_net.onnx``; tools/snout_net_data.py, tools/train_fork_net.py).

A hypothesis is a snout candidate with its axis pointing into the body (towards the fork) and a
span of ``SPAN_OF_FL`` x its distance from the fork, so the crop reaches well ahead of the snout
into the water and back over the head; the net answers the tip. In the survey
(``vision.underwater``, ``Params.snout_net``, on by default) each snout candidate is moved to the
net's tip where the net is at least ``Params.snout_net_min`` sure, and the chosen snouts'
confidence enters the learned score as ``snout_net_conf``.

Measured (2026-12-03, issue 7). Training: 67,679 crops of 750 scenes (seeds 102000-102749,
tools/snout_net_data.py), tools/train_fork_net.py ``--epochs 8 --per-epoch 60000 --threads 2
--val-scenes 60``: 219 s. On the 60 held-out scenes' crops, from one pass: the tip within 3 % of
the fish's length for 92.6 % of jittered candidates (within 1.5 % 77 %, median 0.85 %); 96 % of
crops classified right, 6 % of the negatives over 0.5. In the survey (bench/diag_underwater.py,
seeds 0-39, 75 fully visible fish): fish with no snout candidate within 3 % in both views 12 -> 1;
with the post-filters off, found 42 -> 52.

Its tips were the project's renderer's (2026-12-06): on two outside testers' fish it was as sure
(>= 0.97) of tips ~1 % of the length inside a tapered snout, and those fish read short (right /
wrong 15 / 23 on the second tester's pairs). Started round the true tips (README,
"Snout and fork shapes"), its error followed the snout's shape on the project's own renderer: with
the head's outline going as u^(0.66 + taper) (``devices.sim.fish_body.head_taper``), taper -0.3 /
0 / +0.5 put the tip +0.8 / -0.05 / -1.5 % of the length off (+ ahead of it). It had learned one
head's outline as a prior, and it could not see past it: a crop's cell is 1.2 % of the length.
Now (2026-12-06, thirtieth session) it is trained on snouts of every taper in -0.35..0.8
(``snout_taper``, drawn per fish) and looks twice: the first pass at the usual span, the last at
``FINE`` x it (cells of 0.7 % of the length), with fine crops in its training
(tools/snout_net_data.py). Training: 151,581 crops of 750 scenes (seeds 106000-106749, ``--conditions
'{"snout_taper": [-0.35, 0.8]}'``), ``--epochs 8 --per-epoch 80000 --threads 2 --val-scenes 60``:
373 s; held out, the tip within 3 % for 94.7 % of jittered candidates (1.5 %: 83.2 %, median
0.64 %). Started round the true tips: the testers' fish -0.9 / -1.7 % -> -0.02 / -0.2 %, the
project's +-0.1 %; drawn fish (tests/vision/test_snout_net.py) of snout powers 0.5 .. 1.2 -0.06 ..
-1.74 % -> -0.38 .. +0.27 %. ``Params.snout_to_edge`` is left as it was (off).
"""
from __future__ import annotations

import numpy as np

from vision import fork_net
from vision.fins import SPAN_OF_FL, Fins, down_side

MODEL = "snout_net.onnx"
FINE = 0.6      # the last pass's span: its crop samples the snout 1 / FINE x finer


def refine(pyr: list[np.ndarray], fork_xy: np.ndarray, pts: np.ndarray, passes: int = 2, upright: bool = False
           ) -> tuple[np.ndarray, np.ndarray]:
    """The net's snout tip from each candidate ``pts`` (N, K, 2; NaN: none) of the fish whose forks are
    ``fork_xy`` (N, 2): (tips (N, K, 2), confidence (N, K) 0..1; NaN / 0 where there is no candidate).
    Each pass after the first starts from the previous answer; the last of two or more looks at
    ``FINE`` x the span."""
    N, K = pts.shape[:2]
    flat = pts.reshape(-1, 2)
    has = np.flatnonzero(np.all(np.isfinite(flat), axis=1))
    tips = np.full((N * K, 2), np.nan)
    conf = np.zeros(N * K)
    if len(has) == 0:
        return tips.reshape(N, K, 2), conf.reshape(N, K)
    fork = np.repeat(np.asarray(fork_xy, float), K, axis=0)[has]
    xy = flat[has]
    d = fork - xy
    span = SPAN_OF_FL * np.maximum(np.hypot(d[:, 0], d[:, 1]), 1.0)
    angle = np.arctan2(d[:, 1], d[:, 0])
    z = np.zeros(len(has))
    # upright: the crop's axis points into the body, away from the head: its handedness is the head's
    # (``fins.down_side`` of the fish's own heading), so every fish is seen swimming towards +u,
    # as the fork locator sees it (of the two, the one the net answers best on an outside
    # renderer's fish: tips within 3 % and sure 0.66 of them, 0.33 the other way)
    xy, _, c = fork_net.follow(pyr, Fins(xy, angle, span, z, z), MODEL, passes, FINE,
                               (lambda a: -down_side(a)) if upright else None)
    tips[has] = xy
    conf[has] = c
    return tips.reshape(N, K, 2), conf.reshape(N, K)
