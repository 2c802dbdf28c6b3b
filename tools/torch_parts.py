"""Layers the training scripts share (torch: their separate venv only, see their docstrings)."""
from __future__ import annotations

from torch import nn


def sep_conv(cin: int, cout: int, stride: int = 1, dil: int = 1) -> nn.Sequential:
    """Depthwise 3×3 then pointwise 1×1, each batch-normed: cheap enough for one core."""
    return nn.Sequential(nn.Conv2d(cin, cin, 3, stride, dil, dil, groups=cin, bias=False), nn.BatchNorm2d(cin),
                         nn.ReLU(), nn.Conv2d(cin, cout, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU())
