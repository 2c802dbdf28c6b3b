"""Named pond clips with ground truth: a scene and the float's track (t_s, pose, occlusion).

The pond is the HIL pond (20 m x 10 m, a drain and a feeder kept out), filmed from a tower on its
south bank (where along it, how far back and how high drawn from the seed); the robot's heading is the
marker's, not its direction of travel: a current makes it crab a little. Occlusions (an occluder
passing over the float) ramp in and out over 0.12 s around the fully hidden span.
"""
from __future__ import annotations

import math

import numpy as np

from devices.sim.pond_camera import FloatPose, tower_view
from devices.sim.pond_scene import PondScene

POND = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 10.0], [0.0, 10.0]])
KEEPOUTS = (np.array([[4.4, 4.4], [5.6, 4.4], [5.6, 5.6], [4.4, 5.6]]),        # drain
            np.array([[13.5, 6.0], [15.0, 6.0], [15.0, 7.0], [13.5, 7.0]]))    # feeder
RAMP_S = 0.12
Track = list[tuple[float, FloatPose | None, float]]


def wrap(a: np.ndarray | float) -> np.ndarray:
    """Angles into (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(a, float), 2 * np.pi)


def arc(c, r: float, a0: float, a1: float, n: int = 24) -> np.ndarray:
    a = np.linspace(a0, a1, n)
    return np.c_[c[0] + r * np.cos(a), c[1] + r * np.sin(a)]


def along(path: np.ndarray, speed: float, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions, directions of travel) at ``times`` driving ``path`` at ``speed`` (stops at its end)."""
    seg = np.diff(path, axis=0)
    s = np.r_[0.0, np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))]
    d = np.minimum(times * speed, s[-1])
    xy = np.c_[np.interp(d, s, path[:, 0]), np.interp(d, s, path[:, 1])]
    ahead = np.c_[np.interp(d + 0.05, s, path[:, 0]), np.interp(d + 0.05, s, path[:, 1])]
    behind = np.c_[np.interp(d - 0.05, s, path[:, 0]), np.interp(d - 0.05, s, path[:, 1])]
    v = ahead - behind
    return xy, np.arctan2(v[:, 1], v[:, 0])


def hidden(times: np.ndarray, spans: list[tuple[float, float]]) -> np.ndarray:
    """Occlusion per time: 1 inside each fully hidden span, ramping over RAMP_S on either side."""
    occ = np.zeros_like(times)
    for a, b in spans:
        occ = np.maximum(occ, np.clip(np.minimum(times - a + RAMP_S, b + RAMP_S - times) / RAMP_S, 0, 1))
    return occ


def lawnmower_path(x0=2.0, x1=18.0, y0=1.5, y1=8.5, spacing=1.75) -> np.ndarray:
    pts, y, right = [], y0, True
    while y <= y1 + 1e-9:
        a, b = (x0, x1) if right else (x1, x0)
        pts.append([[a, y], [b, y]])
        if y + spacing <= y1 + 1e-9:
            c = (b, y + spacing / 2)
            pts.append(arc(c, spacing / 2, -math.pi / 2, math.pi / 2) if right
                       else arc(c, spacing / 2, -math.pi / 2, -3 * math.pi / 2))
        y, right = y + spacing, not right
    return np.vstack(pts)


def _drive(path: np.ndarray, speed: float, times: np.ndarray, rng: np.random.Generator,
           crab: float = 0.12) -> list[FloatPose]:
    xy, travel = along(path, speed, times)
    drift = crab * np.sin(2 * math.pi * times / rng.uniform(15, 30) + rng.uniform(0, 6.3))
    heading = wrap(travel + drift + 0.02 * np.sin(2 * math.pi * times / 2.3))
    return [FloatPose(float(x), float(y), float(h)) for (x, y), h in zip(xy, heading, strict=True)]


def _turns(times: np.ndarray, rng: np.random.Generator) -> list[FloatPose]:
    """A figure of eight, then spins on the spot through +-pi both ways."""
    out = []
    c = np.array([10.0, 5.0]) + rng.uniform(-1, 1, 2)
    for t in times:
        if t < 20:
            a = 2 * math.pi * t / 20
            x, y = c[0] + 3.0 * math.sin(a), c[1] + 1.8 * math.sin(2 * a)
            dx, dy = 3.0 * math.cos(a), 3.6 * math.cos(2 * a)
            h = math.atan2(dy, dx) + 0.1 * math.sin(t)
        else:
            x, y = c[0], c[1]
            h = 1.2 * (t - 20) if t < 25 else 6.0 - 1.0 * (t - 25)
        out.append(FloatPose(x, y, float(wrap(h))))
    return out


SCENARIOS: dict[str, tuple[float, dict]] = {         # name: (default duration s, conditions)
    "straight": (20.0, {}), "lawnmower": (60.0, {}), "turns": (30.0, {}), "dropouts": (30.0, {}),
    "long_occlusion": (34.0, {}), "glare": (30.0, {"glare": 0.9, "light": 1.3}),
    "distractors": (30.0, {"distractors": 14}), "washover": (30.0, {"washover": 0.75, "ripple": 0.9}),
    "foam": (30.0, {"foam": 0.22, "ripple": 0.8}),
}


def scenario(name: str, *, seed: int = 0, width: int = 1280, height: int = 720, fps: float = 25.0,
             duration_s: float | None = None, conditions: dict | None = None, tower_xy=None,
             tower_height_m: float | None = None) -> tuple[PondScene, Track]:
    """The scene and track of a named clip: see SCENARIOS for the names. ``conditions`` override
    the scenario's (e.g. distractors in the glare clip); the tower's place and height, drawn
    from the seed on the south bank unless given."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}: one of {', '.join(SCENARIOS)}")
    if not fps > 0:
        raise ValueError(f"fps {fps} must be > 0")
    default_s, cond = SCENARIOS[name]
    duration = default_s if duration_s is None else float(duration_s)
    if not duration > 0:
        raise ValueError(f"duration {duration} must be > 0")
    rng = np.random.default_rng([seed, 7])
    times = np.arange(int(round(duration * fps))) / fps
    cond = {**cond, **(conditions or {})}
    poses, spans = _poses(name, times, rng, cond)
    tower = (10.0 + rng.uniform(-4, 4), -rng.uniform(3.0, 6.0))      # somewhere on the south bank
    height_m = float(rng.uniform(7, 11))
    view = tower_view(POND, width=width, height=height, tower_xy=tower if tower_xy is None else tower_xy,
                      tower_height_m=height_m if tower_height_m is None else tower_height_m)
    scene = PondScene(view, POND, KEEPOUTS, seed=seed, conditions=cond)
    occ = hidden(times, spans)
    return scene, [(float(t), p, float(o)) for t, p, o in zip(times, poses, occ, strict=True)]


def _poses(name: str, times: np.ndarray, rng: np.random.Generator, cond: dict):
    """The float's poses and the fully hidden spans of a named clip (conditions completed in place)."""
    spans: list[tuple[float, float]] = []
    if name == "lawnmower":
        return _drive(lawnmower_path(), 0.8, times, rng), spans
    if name == "turns":
        return _turns(times, rng), spans
    if name == "straight":
        start = np.array([2.5, 2.0]) + rng.uniform(-0.5, 0.5, 2)
        heading = rng.uniform(0.15, 0.35)
        path = np.array([start, start + 18.0 * np.array([math.cos(heading), math.sin(heading)])])
    else:
        path = _wander(rng)
    poses = _drive(path, 0.5, times, rng)
    if name == "dropouts":
        spans = [(4.0, 5.0), (9.0, 11.0), (15.0, 18.0), (23.0, 24.5)]
    elif name == "long_occlusion":
        spans = [(12.0, 22.0)]                # inside one occluder episode (12-24 s)
    elif name in ("glare", "foam") and poses:
        mid = poses[len(poses) // 2]
        cond.setdefault("glare_xy", [mid.x_m, mid.y_m])
    return poses, spans


def _wander(rng: np.random.Generator) -> np.ndarray:
    """A gently curving closed drive around the pond's middle (a figure of eight), as points."""
    c = np.array([10.0, 5.0]) + rng.uniform(-1, 1, 2)
    ax, ay = rng.uniform(6, 7.5), rng.uniform(3, 3.6)
    a = np.linspace(0, 2 * math.pi, 400) + rng.uniform(0, 2 * math.pi)
    return np.c_[c[0] + ax * np.sin(a), c[1] + ay * np.sin(2 * a)]
