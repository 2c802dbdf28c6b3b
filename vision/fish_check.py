"""A learned check of a whole report: does the segment from a fork to a snout, seen in one image,
hold one fish from its caudal notch to its snout tip?

The locators look at each end alone, through a window of a few spans; the score's other figures
say how the ends agree across the views. None of them looks at the fish between the ends. This
net does: an oriented crop from 0.15 of the length behind the fork to 0.15 ahead of the snout,
+-0.32 of the length across (``GRID_H`` x ``GRID_W`` samples, v down the image so a fish is seen
with its back up whichever way it swims), normalised as the crop nets' are, gives the chance
both ends lie within 3 % of the length of one fish's own (the bench's rule in the image).

Shapes: ``fork_xy``, ``snout_xy`` (N, 2) px in the image; ``crops`` (N, 3, GRID_H, GRID_W)
float32; ``chance`` (N,) 0..1 (NaN ends give 0). Trained by tools/train_fish_check.py on crops
of tools/fish_check_data.py (rendered seeds >= 100000 only).
"""
from __future__ import annotations

from importlib import resources

import numpy as np

from vision import onnx_nets
from vision.fins import down_side, sample_frames_raw
from vision.fork_net import normalise

MODEL = "fish_check.onnx"
GRID_H, GRID_W = 32, 96
U0, U1 = -0.15, 1.15        # along the fork -> snout segment, in lengths
V1 = 0.32                   # across, in lengths
BATCH = 32


def available() -> bool:
    """Whether the packaged model is there (the feature is off without it)."""
    return resources.files("vision.models").joinpath(MODEL).is_file()


def raw_crops(pyr: list[np.ndarray], fork_xy: np.ndarray, snout_xy: np.ndarray) -> np.ndarray:
    """(N, GRID_H, GRID_W, 3) uint8 crops (grey: three equal channels); NaN ends give zeros."""
    fork_xy, snout_xy = np.asarray(fork_xy, float).reshape(-1, 2), np.asarray(snout_xy, float).reshape(-1, 2)
    N = len(fork_xy)
    out = np.zeros((N, GRID_H, GRID_W, 3), np.uint8)
    d = snout_xy - fork_xy
    length = np.hypot(d[:, 0], d[:, 1])
    ok = np.flatnonzero(np.isfinite(length) & (length > 1.0))
    if len(ok) == 0:
        return out
    angle = np.arctan2(d[ok, 1], d[ok, 0])
    axes = np.column_stack((np.cos(angle), np.sin(angle)))
    side = down_side(angle)
    L = length[ok]
    step = L * (U1 - U0) / GRID_W
    lev = np.clip(np.floor(np.log2(np.maximum(step, 1.0))).astype(int), 0, len(pyr) - 1)
    us = U0 + (np.arange(GRID_W) + 0.5) * (U1 - U0) / GRID_W
    vs = -V1 + (np.arange(GRID_H) + 0.5) * (2 * V1) / GRID_H
    for k in np.unique(lev):
        idx = np.flatnonzero(lev == k)
        f = 2.0 ** -k
        xs = us[None] * (L[idx] * f)[:, None]
        ys = vs[None] * (L[idx] * f * side[idx])[:, None]
        P, _ = sample_frames_raw(pyr[k], (fork_xy[ok[idx]] + 0.5) * f - 0.5, axes[idx], xs, ys)
        P = np.asarray(P).reshape(len(idx), GRID_H, GRID_W, -1)
        out[ok[idx]] = np.repeat(P, 3, axis=3) if P.shape[3] == 1 else P
    return out


def crops(pyr: list[np.ndarray], fork_xy: np.ndarray, snout_xy: np.ndarray) -> np.ndarray:
    """(N, 3, GRID_H, GRID_W) float32 normalised crops (the net's input)."""
    return normalise(raw_crops(pyr, fork_xy, snout_xy).transpose(0, 3, 1, 2))


def chance(pyr: list[np.ndarray], fork_xy: np.ndarray, snout_xy: np.ndarray, model: str = MODEL) -> np.ndarray:
    """(N,) the net's chance that each segment runs from one fish's fork to its snout."""
    fork_xy, snout_xy = np.asarray(fork_xy, float).reshape(-1, 2), np.asarray(snout_xy, float).reshape(-1, 2)
    x = crops(pyr, fork_xy, snout_xy)
    logits = [onnx_nets.forward(model, x[k:k + BATCH])[0].reshape(-1) for k in range(0, len(x), BATCH)]
    z = np.concatenate(logits) if logits else np.zeros(0)
    p = 1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))
    bad = ~(np.all(np.isfinite(fork_xy), axis=1) & np.all(np.isfinite(snout_xy), axis=1))
    p[bad] = 0.0
    return p
