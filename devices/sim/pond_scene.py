"""A pond scene seen from the tower: what the simulated tower camera films at any time and pose.

``PondScene(view, outline, keepouts, seed=, conditions=)`` precomputes the static picture once;
``render(t_s, pose, occlusion=)`` is then a pure function of its arguments (no state advances
between frames), so a live camera and a clip writer give the same frame for the same time.

Conditions (each optional; unknown keys are a ValueError naming the key; defaults drawn from the
seed): light (gain, 0.3..1.6), water_bgr, bank_bgr (BGR 0..255), ripple (0..1), wind_deg,
glare (0..1: strength of the sun's glitter path), glare_xy (pond m: its centre), foam (0..1:
fraction of water under foam), washover (0..1: how opaque the waves running over the float get),
vignette (0..0.8), noise (sensor noise, grey levels), distractors (count of orange buoys,
lifebuoys, blue objects and reflected bank objects), sun_az_deg (the light's direction on the float),
tint_bgr (white balance: a gain per channel), flicker (0..0.3: light varying as clouds cross the sun),
clouds (0..1: how dark the shadows of clouds drifting over the pond are).
"""
from __future__ import annotations

import math
import numbers
import zlib

import cv2
import numpy as np

from devices.sim.pond_camera import FloatPose, TowerView
from devices.sim.pond_distractors import Floating, draw_bank, make_things
from devices.sim.pond_float import OCCLUDERS, draw_float, draw_occluder, hsv_bgr
from devices.sim.pond_surface import CloudShadows, Surface, grid_step
from devices.sim.pond_water import glitter_zone, static_layer

RANGES = {"light": (0.3, 1.6), "ripple": (0.0, 1.0), "wind_deg": (-360.0, 360.0), "glare": (0.0, 1.0),
          "foam": (0.0, 1.0), "washover": (0.0, 1.0), "vignette": (0.0, 0.8), "noise": (0.0, 20.0),
          "distractors": (0, 40), "sun_az_deg": (-360.0, 360.0), "flicker": (0.0, 0.3), "clouds": (0.0, 1.0)}
VECTORS = {"water_bgr": 3, "bank_bgr": 3, "glare_xy": 2, "tint_bgr": 3}
OCCLUSION_EPISODE_S = 12.0    # an automatic occluder keeps its kind and direction this long


def scene_conditions(outline: np.ndarray, seed: int, given: dict | None) -> dict:
    """The scene's conditions: ``given`` checked by name and range, the rest drawn from ``seed``."""
    rng = np.random.default_rng([seed, 1])
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    cond = {"light": rng.uniform(0.8, 1.1), "water_bgr": rng.uniform([35, 60, 45], [65, 95, 80]),
            "bank_bgr": rng.uniform([35, 85, 55], [65, 120, 95]), "ripple": rng.uniform(0.3, 0.7),
            "wind_deg": rng.uniform(0, 360), "glare": rng.uniform(0.1, 0.35),
            "glare_xy": rng.uniform(lo, hi), "foam": rng.uniform(0.0, 0.12), "washover": 0.0,
            "vignette": rng.uniform(0.15, 0.35), "noise": rng.uniform(1.5, 3.5), "distractors": 0,
            "sun_az_deg": rng.uniform(-180, 180), "tint_bgr": rng.uniform(0.9, 1.1, 3), "flicker": 0.04,
            "clouds": rng.uniform(0.0, 0.35)}
    for key, value in (given or {}).items():
        if key in RANGES:
            a, b = RANGES[key]
            if not isinstance(value, numbers.Real) or isinstance(value, bool) or not a <= value <= b:
                raise ValueError(f"conditions: {key} = {value!r} is outside {a}..{b}")
        elif key in VECTORS:
            v = np.asarray(value, float)
            if v.shape != (VECTORS[key],) or not np.all(np.isfinite(v)):
                raise ValueError(f"conditions: {key} needs {VECTORS[key]} finite numbers")
            value = v
        else:
            raise ValueError(f"conditions: unknown key {key!r}")
        cond[key] = float(value) if key in RANGES else value
    cond["distractors"] = int(cond["distractors"])
    return cond


class PondScene:
    """The pond filmed by the tower camera ``view``: bank, rim, water, float, distractors."""

    def __init__(self, view: TowerView, outline_xy, keepouts=(), *, seed: int = 0, conditions: dict | None = None):
        self.view = view
        self.outline = np.asarray(outline_xy, float).reshape(-1, 2)
        if len(self.outline) < 3 or not np.all(np.isfinite(self.outline)):
            raise ValueError("the pond outline needs at least 3 finite (x, y) points")
        self.keepouts = tuple(np.asarray(k, float).reshape(-1, 2) for k in keepouts)
        self.seed = int(seed)
        self.conditions = scene_conditions(self.outline, self.seed, conditions)
        cond = self.conditions
        rng = np.random.default_rng([self.seed, 2])
        base, water, vign = static_layer(view, self.outline, self.keepouts, cond, rng)
        self.water = water
        self._vign = vign
        tint = np.asarray(cond["tint_bgr"], np.float32)
        self.base = np.clip(base * tint * vign[..., None], 0, 255).astype(np.uint8)
        lum = cv2.cvtColor(self.base, cv2.COLOR_BGR2GRAY).astype(np.float32)
        self.clouds = CloudShadows(view, lum, grid_step(view), cond, np.random.default_rng([self.seed, 5]))
        self.surface = Surface(view, water, vign, cond, rng, self.clouds)
        self.look = self._look(rng)
        self.things = make_things(self.outline, view, cond["distractors"], np.random.default_rng([self.seed, 4]))
        draw_bank(self.base, view, self.things, self.look, water)
        self.floating = Floating(view, self.things, self.look)
        self._noise = self._noise_layers(rng)

    def _look(self, rng: np.random.Generator) -> dict:
        """The float's paint this scene: orange and blue a little off any one RGB, lit by the sun."""
        vign = self._vign
        return {"orange": hsv_bgr(rng.uniform(6, 16), rng.uniform(0.78, 0.97), rng.uniform(0.86, 1.0)),
                "blue": hsv_bgr(rng.uniform(100, 114), rng.uniform(0.65, 0.95), rng.uniform(0.6, 0.9)),
                "light": self.conditions["light"] * np.asarray(self.conditions["tint_bgr"], np.float32),
                "shade": rng.uniform(0.08, 0.2), "glare_at": self._glare_at, "sun_at": self.clouds.at,
                "sun_az": math.radians(self.conditions["sun_az_deg"]),
                "vignette": lambda roi: roi.of(vign)[..., None]}

    def _glare_at(self, x_m: float, y_m: float) -> float:
        """How deep in the sun's glitter path a pond point is (0..1)."""
        g = glitter_zone(np.array([[x_m, y_m]]), self.view, self.conditions)
        return float(np.clip(g[0] * 1.6, 0, 1))

    def _noise_layers(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray] | None:
        sigma = self.conditions["noise"]
        if sigma <= 0:
            return None
        n = rng.normal(0.0, sigma, (self.view.height + 64, self.view.width + 64, 3)).astype(np.float32)
        return np.clip(n, 0, 255).astype(np.uint8), np.clip(-n, 0, 255).astype(np.uint8)

    def render(self, t_s: float, pose: FloatPose | None, *, occlusion: float = 0.0,
               occluder: str | None = None) -> np.ndarray:
        """The BGR uint8 (height, width, 3) frame at farm time ``t_s`` with the float at ``pose``
        (None: no float in the pond); ``occlusion`` in [0, 1] is the fraction of the float hidden
        under an occluder (``occluder``: "boat", "bird" or "spray"; by default one chosen per
        12 s episode from the seed)."""
        t_s = float(t_s)
        if not math.isfinite(t_s):
            raise ValueError(f"t_s {t_s} is not finite")
        if not 0.0 <= occlusion <= 1.0:
            raise ValueError(f"occlusion {occlusion} is outside 0..1")
        if occluder is not None and occluder not in OCCLUDERS:
            raise ValueError(f"occluder {occluder!r} is not one of {', '.join(OCCLUDERS)}")
        up, down = self.surface.layers(t_s)
        frame = cv2.add(self.base, up)
        cv2.subtract(frame, down, dst=frame)
        self.floating.draw(frame, t_s)
        if pose is not None:
            draw_float(frame, self.view, pose, self.look, t_s, self.conditions["washover"])
            if occlusion > 0:
                kind, d_ang = self._occluder(t_s, occluder)
                draw_occluder(frame, self.view, pose, occlusion, kind, d_ang, self.look)
        flicker = self.conditions["flicker"]
        if flicker > 0:                      # clouds crossing the sun
            gain = 1 + flicker * (0.6 * math.sin(t_s * 0.37 + self.seed) + 0.4 * math.sin(t_s * 0.9 + 2 * self.seed))
            cv2.convertScaleAbs(frame, dst=frame, alpha=gain)
        self._add_noise(frame, t_s)
        return frame

    def _occluder(self, t_s: float, kind: str | None) -> tuple[str, float]:
        episode = int(math.floor(t_s / OCCLUSION_EPISODE_S))
        rng = np.random.default_rng([self.seed, 3, episode & 0xFFFFFFFF])
        pick = OCCLUDERS[int(rng.integers(len(OCCLUDERS)))]
        return kind or pick, float(rng.uniform(-math.pi, math.pi))

    def _add_noise(self, frame: np.ndarray, t_s: float) -> None:
        if self._noise is None:
            return
        key = zlib.crc32(np.float64(t_s).tobytes()) ^ self.seed
        ox, oy = key % 64, (key >> 8) % 64
        h, w = frame.shape[:2]
        pos, neg = self._noise
        cv2.add(frame, pos[oy:oy + h, ox:ox + w], dst=frame)
        cv2.subtract(frame, neg[(oy + 17) % 64:(oy + 17) % 64 + h, ox:ox + w], dst=frame)

