"""What a weight survey measures, shared by the detectors (underwater, surface), the stereo
association, the tracker and the survey entry. Pure data: numpy arrays and dataclasses.

Frames: world millimetres in the calibration's frame (CALIB.json), pixels in OpenCV's convention
(u column, v row, integer coordinates at pixel centres). Index 0 of a (2, 2) pixel array is the
left image (camera 1, P1), index 1 the right (camera 2, P2).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

Setup = Literal["underwater", "surface"]


def plain_image(img: np.ndarray) -> np.ndarray:
    """Grey (H, W) or BGR (H, W, 3): a single channel squeezed, an alpha channel dropped."""
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[2] == 1:
        return img[..., 0]
    if img.ndim == 3 and img.shape[2] == 4:
        return np.ascontiguousarray(img[..., :3])
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"expected a grey (H, W) or colour (H, W, 3) image, got shape {img.shape}")
    return img


@dataclass(frozen=True)
class LengthWeight:
    """W = a * L^b, L fork length in cm, W in g (the paper's section 4.3)."""

    a: float
    b: float

    def weight_g(self, length_cm: np.ndarray | float) -> np.ndarray | float:
        return self.a * np.power(length_cm, self.b)


@dataclass(frozen=True)
class FishGeometry:
    """The species' shape as the 3-D association checks it (config/species.toml)."""

    min_length_cm: float = 3.0          # plausible fork lengths
    max_length_cm: float = 80.0
    max_tilt_deg: float = 35.0          # body axis against the water surface
    depth_to_length: float = 0.38       # body depth / fork length (sea bream ~0.38; salmon ~0.25)
    # Seen from above (surface setup) the caudal fin stands edge-on and its fork is rarely seen: the
    # fork is then placed from the fin's base, at snout + (base - snout) / fin_base_to_fork (the
    # species' standard-to-fork length ratio, ~0.86-0.91). None: the rear end of the fin is used.
    fin_base_to_fork: float | None = None


@dataclass(frozen=True)
class SurveySetup:
    """How a pair is processed: the setup, the paper's illumination references (eqs. 11-12) and
    the species geometry. ``up_world``: the water surface's normal in the calibration's world
    frame; None = the left camera's image-up direction (cameras mounted level). ``floor_mm``
    (surface setup): the tank floor's distance below camera 1 along "up", mm; what lies on it (a
    fish's shadow, debris) is not reported. None: not known, nothing dropped for it."""

    setup: Setup = "underwater"
    mi_ref: float = 120.0
    c_ref: float = 130.0
    geometry: FishGeometry = field(default_factory=FishGeometry)
    up_world: tuple[float, float, float] | None = None
    floor_mm: float | None = None


@dataclass
class FishMeasurement:
    """One fish measured in one stereo pair."""

    snout_mm: np.ndarray                # (3,) world mm, snout tip
    fork_mm: np.ndarray                 # (3,) world mm, innermost point of the caudal fork
    snout_px: np.ndarray                # (2, 2) [[u1, v1], [u2, v2]]
    fork_px: np.ndarray                 # (2, 2)
    score: float                        # 0..1: how far the measurement can be trusted
    quality: dict[str, float] = field(default_factory=dict)   # the terms behind ``score``

    @property
    def length_cm(self) -> float:
        return float(np.linalg.norm(np.asarray(self.snout_mm) - np.asarray(self.fork_mm)) / 10.0)
