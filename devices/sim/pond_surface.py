"""What moves on the water between frames: ripples, sun glints and drifting foam.

Each is evaluated at time t on a grid of every ``step``-th pixel from maps precomputed per scene:
ripples are travelling waves (deep-water dispersion) whose phases are stored as 8-bit angles, so a
wave costs one wrapped uint8 add and one table look-up; glints are where the short waves' crests
line up inside the sun's glitter path, saturated white; foam is a streaky texture on the pond
plane sampled through the pixels' pond coordinates, shifted by the drift. The result is two
uint8 layers the frame brightens and darkens by.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from devices.sim.pond_camera import TowerView
from devices.sim.pond_water import glitter_zone, pixel_rays
from devices.sim.stereo_scene import random_texture

GRAVITY = 9.81
TWO_PI = 2 * math.pi
FOAM_TEXEL_M = 0.05
FOAM_DRIFT_M_S = 0.06


def grid_step(view: TowerView) -> int:
    """Pixels between samples of what moves: every other pixel on frames 800 wide and over,
    every third from 1600 (a 1920x1080 frame's waves on the same 640x360 grid as 1280x720's)."""
    return 1 if view.width < 800 else 2 if view.width < 1600 else 3


class Waves:
    """A sum of travelling sinusoids over the pond plane, sampled on the pixel grid ``xy``."""

    def __init__(self, xy: np.ndarray, rng: np.random.Generator, lam: tuple[float, float], n: int, wind: float,
                 spread: float):
        lam_m = rng.uniform(*lam, n)
        ang = wind + rng.normal(0.0, spread, n)
        k = TWO_PI / lam_m
        self.omega = np.sqrt(GRAVITY * k)
        self.phase = []
        for i in range(n):
            p = k[i] * (xy[..., 0] * math.cos(ang[i]) + xy[..., 1] * math.sin(ang[i])) + rng.uniform(0, TWO_PI)
            self.phase.append(np.mod(np.round(p * (256 / TWO_PI)), 256).astype(np.uint8))
        amp = rng.uniform(0.6, 1.0, n)
        cos = np.cos(np.arange(256) * (TWO_PI / 256))
        self.luts = [(a * cos).astype(np.float32) for a in amp / amp.sum()]   # each wave's share, pre-scaled

    def at(self, t_s: float) -> np.ndarray:
        """The waves' sum in [-1, 1] at time t (float32)."""
        out = np.zeros(self.phase[0].shape, np.float32)
        for ph, om, lut in zip(self.phase, self.omega, self.luts, strict=True):
            shift = np.uint8(int(round(-om * t_s * 256 / TWO_PI)) % 256)
            out += cv2.LUT(ph + shift, lut)
        return out


class Surface:
    """Ripples, glints and foam over the water of ``view`` (``water``: 0..1 coverage, full size;
    ``gain``: per-pixel brightness gain, e.g. vignetting)."""

    def __init__(self, view: TowerView, water: np.ndarray, gain: np.ndarray, cond: dict, rng: np.random.Generator,
                 clouds: CloudShadows | None = None):
        self.clouds = clouds
        self.size = (view.width, view.height)
        self.step = grid_step(view)
        xy, _, cos_i = pixel_rays(view, self.step)
        xy = np.nan_to_num(xy)
        grid = (xy.shape[1], xy.shape[0])
        wind = math.radians(cond["wind_deg"])
        self.swell = Waves(xy, rng, (0.7, 3.0), 5, wind, 0.5)
        self.chop = Waves(xy, rng, (0.18, 0.7), 8, wind, 0.6)
        small = cv2.resize(water * gain, grid, interpolation=cv2.INTER_AREA)
        paws = 0.35 + 1.0 * cv2.resize(random_texture((grid[1] // 8 + 2, grid[0] // 8 + 2), rng, (1.0, 3.0)),
                                       grid, interpolation=cv2.INTER_CUBIC)
        # ripples show most where the water mirrors the sky (grazing rays); gusts ruffle patches of it
        mirror = 0.02 + 0.98 * (1 - cos_i) ** 5
        self.gain = (small * cond["ripple"] * (40 + 220 * mirror) * paws).astype(np.float32)
        zone = glitter_zone(xy, view, cond)
        sparkle = np.clip(random_texture(zone.shape, rng, (1.0, 4.0)) * 2.0 - 0.5, 0, 1)    # glitter comes in patches
        self.glint_gain = (small * np.clip(zone * 1.6, 0, 1) * sparkle * 255).astype(np.float32)
        self.glint_thr = 0.62 - 0.2 * cond["glare"]
        self._foam_init(xy, small, cond, rng, wind)

    def _foam_init(self, xy: np.ndarray, small: np.ndarray, cond: dict, rng: np.random.Generator, wind: float):
        """Foam patches and streaks along the wind, on a texture in wind-aligned pond coordinates."""
        self.foam = None
        if cond["foam"] <= 0:
            return
        c, s = math.cos(wind), math.sin(wind)
        along = xy[..., 0] * c + xy[..., 1] * s
        across = -xy[..., 0] * s + xy[..., 1] * c
        n = 1024 if max(self.size) >= 800 else 512      # texture wraps every n texels (51 or 26 m)
        noise = rng.standard_normal((n, n)).astype(np.float32)
        streaks = cv2.GaussianBlur(noise, (0, 0), sigmaX=16, sigmaY=1.8) * 4 + cv2.GaussianBlur(noise, (0, 0), 24) * 6
        lo, hi = np.percentile(streaks, [1, 99])
        tex = np.clip((streaks - lo) / (hi - lo), 0, 1)
        cut = np.quantile(tex, 1 - cond["foam"])
        lace = np.clip((random_texture((n, n), rng, (0.7, 1.6)) - 0.35) * 3.0, 0, 1)     # bubbles and holes
        self.foam_tex = (np.clip((tex - cut) / 0.12, 0, 1) * (0.35 + 0.65 * lace) * 150).astype(np.uint8)
        # fixed-point maps into the texture (coordinates wrapped once: remap wraps slowly far out)
        u = np.mod(along / FOAM_TEXEL_M, n).astype(np.float32)
        v = np.mod(across / FOAM_TEXEL_M, n).astype(np.float32)
        self.foam_maps = cv2.convertMaps(u, v, cv2.CV_16SC2)
        self.foam = small

    def _foam(self, t_s: float) -> np.ndarray:
        """Foam brightness at time t: the texture drifted downwind (whole texels: 5 cm steps)."""
        drift = int(math.floor(t_s * FOAM_DRIFT_M_S / FOAM_TEXEL_M))
        tex = np.roll(self.foam_tex, drift, axis=1)
        f = cv2.remap(tex, *self.foam_maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        return f * self.foam

    def layers(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(brighten, darken) uint8 (h, w, 3) to add to and subtract from the frame at time t."""
        swell, chop = self.swell.at(t_s), self.chop.at(t_s)
        shade = (0.7 * swell + 0.45 * chop) * self.gain
        crest = np.clip((chop + 0.4 * swell - self.glint_thr) * 6.0, 0, 1)
        up = np.maximum(shade, 0) + crest * self.glint_gain
        if self.foam is not None:
            up += self._foam(t_s)
        down = np.maximum(-shade, 0)
        shadow = self.clouds.layer(t_s) if self.clouds is not None else None
        if shadow is not None:
            down += shadow
        both = np.dstack([up, down])
        both = cv2.convertScaleAbs(both)               # saturates at 255
        if self.step != 1:
            both = cv2.resize(both, self.size, interpolation=cv2.INTER_LINEAR)
        return cv2.cvtColor(both[..., 0], cv2.COLOR_GRAY2BGR), cv2.cvtColor(both[..., 1], cv2.COLOR_GRAY2BGR)


CLOUD_TEXEL_M = 0.5
CLOUD_SPEED_M_S = 1.2
CLOUD_DARKEN = 0.45          # a cloud's shadow at full strength takes this much of the sunlight


class CloudShadows:
    """Shadows of clouds drifting downwind over the pond and its bank: a soft patchy texture on
    the ground plane, sampled every frame on a coarse grid; it darkens the still picture
    (``layer``) and anything painted on top (``at``)."""

    def __init__(self, view: TowerView, base_lum: np.ndarray, step: int, cond: dict, rng: np.random.Generator):
        self.strength = float(cond["clouds"])
        self.size = (-(-view.width // step), -(-view.height // step))
        wind = math.radians(cond["wind_deg"])
        self.drift = CLOUD_SPEED_M_S * np.array([math.cos(wind), math.sin(wind)])
        tex = random_texture((256, 256), rng, (6.0, 14.0))
        self.tex = np.clip((tex - 0.55) * 4.0, 0, 1).astype(np.float32)       # clear sky between clouds
        xy, hits, _ = pixel_rays(view, step * 4)
        self.xy = np.nan_to_num(xy).astype(np.float64)
        self.hits = hits.astype(np.float32)
        self.gain = (cv2.resize(base_lum, self.size, interpolation=cv2.INTER_AREA)
                     * CLOUD_DARKEN * self.strength).astype(np.float32)

    def _sample(self, xy: np.ndarray, t_s: float) -> np.ndarray:
        uv = np.mod((xy - self.drift * t_s) / CLOUD_TEXEL_M, 256.0).astype(np.float32)
        return cv2.remap(self.tex, uv[..., 0], uv[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)

    def layer(self, t_s: float) -> np.ndarray | None:
        """Grey levels to take off the still picture at time t, on the ripple grid (None: no clouds)."""
        if self.strength <= 0:
            return None
        shadow = self._sample(self.xy, t_s) * self.hits
        return cv2.resize(shadow, self.size, interpolation=cv2.INTER_LINEAR) * self.gain

    def at(self, x_m: float, y_m: float, t_s: float) -> float:
        """The light left at a pond point at time t (1: in the sun)."""
        if self.strength <= 0:
            return 1.0
        s = self._sample(np.array([[[x_m, y_m]]]), t_s)[0, 0]
        return float(1 - CLOUD_DARKEN * self.strength * s)
