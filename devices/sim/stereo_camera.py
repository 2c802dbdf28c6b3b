"""The simulated stereo pair on the rail carriage: the survey renderer's fish of the tank under
the carriage, at their size of the moment (they grow: devices/sim/stock.py).

Each frame is one still of the tank (``still_in``: fish placed anew, as independent stills), both
views side by side in one JPEG (4:4:4), served as MJPEG over HTTP by the tower camera's server
(devices/sim/tower_camera.py) and read by the real ``capture`` driver with ``layout =
"side_by_side"``. The water (light, turbidity, clutter, background: ``underwater_water``) is drawn
once a visit, as a camera held at one tank sees it; a visit ends when the carriage's cameras see
another tank or none, or after ``VISIT_GAP_S`` without a frame (the stream closed between
surveys). Away from every tank's mouth the cameras see empty water. The rig's exact calibration
is written as CALIB.json for the driver's section.

Lengths are normal around the mean whose a L^b, averaged over the spread, is the tank's mean
weight (E[L^b] = mu^b (1 + b(b-1)/2 cv^2) to second order), with the renderer's species law —
the species.toml figure the controller measures with.
"""
from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from devices.sim.fish_scene import still_in, underwater_rig, underwater_water
from devices.sim.fish_species import SPECIES

SIZE_SAMPLE = 256         # individuals a still's sizes are drawn from, when the tank keeps them
VISIT_GAP_S = 120.0       # farm s without a frame that end a visit: the next frame sees new water


class SimStereoCameraParams(BaseModel):
    """farm.toml ``[sim.stereo_camera]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    fps: float = Field(2.0, gt=0, le=30, description="pairs per wall second while a survey streams")
    width: int = Field(1280, ge=160, le=2048, description="each view's width")
    height: int = Field(960, ge=120, le=4096)
    focal_px: float = Field(1400.0, gt=0, description="at 1280 px wide; scaled with the width")
    fish_in_view: tuple[int, int] = Field((8, 16), description="fish per still, drawn uniformly")
    jpeg_quality: int = Field(95, ge=10, le=100)
    seed: int = 0

    @model_validator(mode="after")
    def _fish_span(self):
        lo, hi = self.fish_in_view
        if not 0 <= lo <= hi <= 200:
            raise ValueError(f"fish_in_view must be [low, high] with 0 <= low <= high <= 200, not [{lo}, {hi}]")
        return self


class TankView:
    """``render(t)``: the side-by-side pair the carriage's cameras see at farm time ``t``."""

    def __init__(self, params: SimStereoCameraParams, tanks: dict, tank_at: Callable[[float], str | None]):
        self.p, self.tanks, self.tank_at = params, tanks, tank_at
        w = params.width
        self.rig = underwater_rig(image_size=(w, params.height), focal_px=params.focal_px * w / 1280)
        self.rng = np.random.default_rng(params.seed)
        self.seen: list[tuple[float, str | None, float | None]] = []   # (t, tank, its mean weight), last few
        self.visits = 0           # waters drawn
        self._visit: tuple[str | None, float, tuple[dict, dict]] | None = None   # (tank, last frame t, water)

    def render(self, t: float) -> np.ndarray:
        tank_id = self.tank_at(t)
        tank = self.tanks.get(tank_id) if tank_id is not None else None
        lo, hi = self.p.fish_in_view
        if tank is None:
            tank_id, weight, sp, fish = None, None, SPECIES["sparus_aurata"], {"n_fish": 0}
        else:
            sp = SPECIES[tank.species] if tank.species in SPECIES else SPECIES["sparus_aurata"]
            weight, length, cv = self._sizes(tank, sp, t)
            fish = {"n_fish": int(self.rng.integers(lo, hi + 1)), "mean_length_cm": length, "length_cv": cv}
        scene = still_in(self.rng, self.rig, self._water(tank_id, sp.name, t), **fish)
        self.seen = [*self.seen[-63:], (t, tank_id, weight)]
        return np.hstack([scene.left, scene.right])

    def _water(self, tank_id: str | None, species: str, t: float) -> tuple[dict, dict]:
        """The visit's water: kept while the cameras look at the same tank with frames at most
        ``VISIT_GAP_S`` apart, drawn anew otherwise."""
        visit = self._visit
        if visit is None or visit[0] != tank_id or not 0 <= t - visit[1] <= VISIT_GAP_S:
            visit = (tank_id, t, underwater_water(self.rng, self.rig, species=species, jpeg_quality=None))
            self.visits += 1
        self._visit = (tank_id, t, visit[2])
        return visit[2]

    def _sizes(self, tank, sp, t: float) -> tuple[float, float, float]:
        """(mean weight g, mean fork length cm, length CV) of the tank's fish now, drawn from its
        individuals (devices/sim/stock.py: they grow on what they eat and die)."""
        w = np.asarray(tank.stock.weights(SIZE_SAMPLE, self.rng), float)
        lengths = (w / sp.a) ** (1 / sp.b)
        return float(w.mean()), float(lengths.mean()), float(lengths.std() / lengths.mean())

    def write_calibration(self, path: Path) -> str:
        path.write_text(json.dumps(self.rig.calibration().to_json()))
        return str(path)


def frame_size(params: SimStereoCameraParams) -> dict:
    """The served frame's size (both views side by side), for the MJPEG server's check."""
    return {"width": 2 * params.width, "height": params.height}
