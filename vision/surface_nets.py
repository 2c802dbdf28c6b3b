"""Learned end locators for fish seen from above: the snout tip and the body's rear end (the
caudal fin's base), each by the fork locator's net (``vision.fork_net``: a crop along the
hypothesis' axis, a heatmap's soft-argmax and a confidence) trained on rendered nursery tanks
(``vision/models/surface_snout_net.onnx``, ``surface_base_net.onnx``; tools/surface_net_data.py,
tools/train_fork_net.py).

A hypothesis is a region's own end with its axis pointing into the body and a span of
``SPAN_OF_FL`` x the region's snout-fork length, so the crop reaches well out past the end and back
over the body; the net answers the end. Two passes, the last at ``FINE`` x the span. In the survey
(``vision.surface``) a region's snout and body end are moved to the nets' answers where they are
at least ``MIN_CONF`` sure, before the fork is placed from the body's end by the species' ratio.

Measured (2026-12-07, issue 7; README, *Surface fish measurement*, "Learned ends"). Held out (the
last 40 tanks of each net's data), the regions' own ends near a true one, one pass: snouts within
3 % of the length 98.7 % (median 0.37 %), body ends 84.9 % (median 1.09 %; those tanks' fins all
painted in, tools/surface_net_data.py ``paint_fins``). In the survey, per view on tuning tanks
(seeds 7000+): both ends within 3 % 66 -> 81 %.
The body-end net trained again (2026-12-07, forty-first session: 2,400 tanks, 30 epochs;
tools/train_fork_net.py has the commands), on its held-out tanks (seeds 152360-152399, fins all
painted in), the regions' own ends: within 3 % of the length 81.8 -> 91.4 %, within 1.5 % 61.4 ->
70.6 %, median 1.20 -> 0.90 %; negatives scored over 0.5 4.0 -> 2.3 %.

Shapes: ends (N, 2) px, lengths (N,) px; answers (N, 2) and confidences (N,).
"""
from __future__ import annotations

import numpy as np

from vision import fork_net
from vision.fins import SPAN_OF_FL, Fins
from vision.fork import pyramid
from vision.surface_prep import grey

SNOUT_MODEL = "surface_snout_net.onnx"
BASE_MODEL = "surface_base_net.onnx"
PASSES = 2          # each from the previous answer ...
FINE = 0.6          # ... the last at this span, x the first's
MIN_CONF = 0.8      # an end is moved to the net's answer when the net is at least this sure (0.5 and 0.8
                    # gave the bench's tanks the same reports; on fish unlike the renderer's a net can be
                    # less sure, and the region's own end is kept) ...
MIN_MOVE = 0.015    # ... and the answer is further than this share of the length from the region's end:
                    # the nets mend ends a region lost (a pale head, a thin peduncle), not where an edge
                    # is drawn within a pixel -- there they learned the renderer's blur (drawn fish of
                    # 60-90 px, sharper: snouts +0.4-1.0 % past the tip, lengths +1.5 %)


def net_image(img: np.ndarray) -> np.ndarray:
    """The image as the nets were trained on it: uint8, grey or BGR."""
    img = np.asarray(img)
    if img.dtype == np.uint8 and (img.ndim == 2 or img.shape[2] == 3):
        return img
    return grey(img)


def hypotheses(snouts: np.ndarray, bases: np.ndarray, forks: np.ndarray, lengths: np.ndarray
               ) -> tuple[Fins, Fins]:
    """The nets' hypotheses from regions' ends (N, 2 each; ``lengths`` (N,) px): the snouts with
    their axis into the body, the body ends with theirs towards the head, a span of ``SPAN_OF_FL`` x
    the length (tools/surface_net_data.py trains on the same)."""
    snouts = np.asarray(snouts, float).reshape(-1, 2)
    d = np.asarray(forks, float).reshape(-1, 2) - snouts
    into = np.arctan2(d[:, 1], d[:, 0])              # from the snout into the body
    span = SPAN_OF_FL * np.maximum(np.asarray(lengths, float), 8.0)
    z = np.zeros(len(snouts))
    return (Fins(snouts, into, span, z, z.copy()),
            Fins(np.asarray(bases, float).reshape(-1, 2), into + np.pi, span.copy(), z.copy(), z.copy()))


def refine_ends(img: np.ndarray, snouts: np.ndarray, bases: np.ndarray, forks: np.ndarray,
                lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Snout tips and body ends (N, 2 each) located by the nets from a region's own (``snouts``,
    ``bases``; ``forks`` and ``lengths`` give each fish's axis and size) and the nets' confidence
    (N,) each."""
    at_snout, at_base = hypotheses(snouts, bases, forks, lengths)
    if len(at_snout) == 0:
        return at_snout.xy, np.zeros(0), at_base.xy, np.zeros(0)
    # only the levels the crops sample (``fork_net.raw_crops``): a colour level costs ~1 ms at 1280x960
    step = at_snout.span_px.max() * (fork_net.U1 - fork_net.U0) / fork_net.GRID_W
    pyr = pyramid(net_image(img), levels=1 + max(int(np.floor(np.log2(max(step, 1.0)))), 0))
    s, _, cs = fork_net.follow(pyr, at_snout, SNOUT_MODEL, PASSES, FINE)
    b, _, cb = fork_net.follow(pyr, at_base, BASE_MODEL, PASSES, FINE)
    return s, cs, b, cb
