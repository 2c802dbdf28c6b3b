"""Scene conditions of the simulated stereo camera, drawn per scene from the caller's generator.

Every name below can be given as a keyword to ``underwater_scene`` / ``surface_scene`` / ``swim``
to fix it; the rest are drawn, so a benchmark sweeping seeds sees varied water, light, stock and
clutter. Unknown names raise ValueError naming them. Two backdrops are never drawn, only given
(``clutter="rock"``, ``"cage"``: more contrast than the drawn net and reef can have, for training
data and diagnosis), so the benches' seeds render what they always did. A scene reports what it drew
(``SurveyScene.conditions``).
"""
from __future__ import annotations

import numpy as np

from devices.sim.fish_body import NOTCH_POWER
from devices.sim.fish_species import SPECIES
from devices.sim.fish_water import cage_net_texture, net_texture, ripple_texture, rock_texture
from devices.sim.stereo_scene import random_texture

_SPECIES_ODDS = {"sparus_aurata": 0.4, "dicentrarchus_labrax": 0.15, "salmo_salar": 0.15,
                 "oncorhynchus_mykiss": 0.15, "oreochromis_niloticus": 0.15}


def _species(rng, c):
    names = list(_SPECIES_ODDS)
    return str(rng.choice(names, p=list(_SPECIES_ODDS.values())))


def _log_uniform(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _jpeg(rng, c):
    """None (lossless) for 60 % of scenes, else a JPEG quality 60..95."""
    return int(rng.integers(60, 96)) if rng.random() < 0.4 else None


def _water_bgr(rng, c):
    green = rng.uniform(0.0, 1.0)                     # 0 blue ocean .. 1 green coastal water
    return [float(rng.uniform(0.8, 1.0) - 0.25 * green), float(rng.uniform(0.75, 0.95)),
            float(rng.uniform(0.2, 0.45) + 0.1 * green)]


# name -> drawer(rng, conditions so far); order matters where one depends on another
UNDERWATER = {
    "species": _species,
    "mean_length_cm": lambda r, c: float(r.uniform(*SPECIES[c["species"]].mean_length_cm)),
    "length_cv": lambda r, c: float(r.uniform(0.10, 0.15)),
    "weight_scatter": lambda r, c: 0.05,               # sd of log condition factor
    "n_fish": lambda r, c: int(r.integers(3, 21)),
    "range_mm": lambda r, c: [600.0, 2000.0],
    "frame_margin": lambda r, c: 0.15,                 # fish centres placed this far beyond the edges
    "yaw_sd_deg": lambda r, c: float(r.uniform(12, 30)),   # heading off side-on
    "max_yaw_deg": lambda r, c: 60.0,
    "max_pitch_deg": lambda r, c: 20.0,
    "max_roll_deg": lambda r, c: 20.0,
    "bend": lambda r, c: float(r.uniform(0.0, 0.05)),   # sd of the tail's sideways offset / L
    "visibility_mm": lambda r, c: _log_uniform(r, 2500, 12000),
    "gradient": lambda r, c: float(r.uniform(0.25, 0.9)),
    "water_brightness": lambda r, c: float(r.uniform(70, 140)),
    "water_bgr": _water_bgr,
    "light_bgr": lambda r, c: [float(v) for v in r.uniform([200, 200, 110], [255, 250, 190])],
    "sun_tilt_deg": lambda r, c: float(r.uniform(0, 30)),
    "sun_azimuth_deg": lambda r, c: float(r.uniform(0, 360)),
    "sun_rays": lambda r, c: float(r.uniform(0.1, 0.6)) if r.random() < 0.5 else 0.0,   # light shafts
    "_rays_seed": lambda r, c: int(r.integers(1 << 30)),
    "light_attenuation_mm": lambda r, c: float(r.uniform(1500, 6000)),
    "ambient": lambda r, c: float(r.uniform(0.45, 0.8)),    # underwater light is diffuse
    # "rock" and "cage" only when given: drawn scenes keep every seed's draws (the benches' sets)
    "clutter": lambda r, c: str(r.choice(["none", "net", "reef"], p=[0.4, 0.3, 0.3])),
    "clutter_range_mm": lambda r, c: float(r.uniform(2300, 3500)),
    "net_bgr": lambda r, c: [float(v) for v in r.uniform(0.2, 0.6) * r.uniform(0.8, 1.2, 3) * 255],
    "reef_bgr": lambda r, c: [float(v) for v in r.uniform([0.25, 0.3, 0.3], [0.45, 0.55, 0.6]) * 255],
    "bubbles": lambda r, c: int(r.integers(0, 60)) if r.random() < 0.7 else 0,
    "fish_gain": lambda r, c: _log_uniform(r, 0.6, 2.2),    # fish darker .. brighter than the water
    "shade": lambda r, c: float(r.uniform(0.05, 0.35)),      # darkening of the water under a fish
    "shade_drop": lambda r, c: float(r.uniform(0.6, 1.5)),   # how far under it, in body depths
    "focus_mm": lambda r, c: float(r.uniform(900, 1400)),
    "blur_gain": lambda r, c: float(r.uniform(0.3, 1.8)),
    "noise_sd": lambda r, c: float(r.uniform(1.0, 4.0)),
    "particles": lambda r, c: int(r.integers(50, 600)) if r.random() < 0.6 else 0,   # marine snow
    "_snow_seed": lambda r, c: int(r.integers(1 << 30)),
    "vignette": lambda r, c: float(r.uniform(0.0, 0.4)),
    "camera_gain": lambda r, c: [1.0, float(np.exp(r.normal(0, 0.04)))],   # left, right
    "jpeg_quality": _jpeg,
    "speed_bl_s": lambda r, c: [0.5, 1.5],
    # each fish's snout (fish_body.head_taper) and fork (its notch_power) drawn from [lo, hi]; one
    # value draws nothing
    "snout_taper": lambda r, c: [0.0, 0.0],
    "notch_power": lambda r, c: [NOTCH_POWER, NOTCH_POWER],
}

CLUTTER = ("none", "net", "reef", "rock", "cage")

SURFACE = {
    "species": _species,
    "mean_length_cm": lambda r, c: float(r.uniform(*SPECIES[c["species"]].nursery_length_cm)),
    "length_cv": lambda r, c: float(r.uniform(0.10, 0.15)),
    "weight_scatter": lambda r, c: 0.05,
    "n_fish": lambda r, c: int(r.integers(5, 31)),
    "floor_depth_mm": lambda r, c: float(r.uniform(400, 700)),
    "swim_depth_mm": lambda r, c: [40.0, c["floor_depth_mm"] - 80.0],
    "frame_margin": lambda r, c: 0.15,
    "max_pitch_deg": lambda r, c: 12.0,
    "max_roll_deg": lambda r, c: 12.0,
    "bend": lambda r, c: float(r.uniform(0.0, 0.06)),
    "visibility_mm": lambda r, c: _log_uniform(r, 3000, 15000),
    "water_bgr": lambda r, c: [float(v) for v in r.uniform([90, 100, 80], [150, 150, 120])],
    "floor_bgr": lambda r, c: _floor_bgr(r),
    "floor_texture": lambda r, c: float(r.uniform(0.05, 0.5)),
    "lamps": lambda r, c: _lamps(r),
    "light_bgr": lambda r, c: [float(v) for v in r.uniform([200, 210, 210], [255, 255, 255])],
    "ambient": lambda r, c: float(r.uniform(0.3, 0.5)),
    "glare_px": lambda r, c: float(r.uniform(150, 450)),     # spread of the ripples' glitter
    "glare_strength": lambda r, c: float(r.uniform(0.3, 1.0)),
    "sheen": lambda r, c: float(r.uniform(0.0, 0.12)),
    "bubbles": lambda r, c: int(r.integers(0, 15)) if r.random() < 0.3 else 0,
    "fish_gain": lambda r, c: float(r.uniform(0.5, 1.3)),
    "shade": lambda r, c: float(r.uniform(0.1, 0.5)),        # shadows on the tank floor
    "focus_mm": lambda r, c: 1200.0,
    "blur_gain": lambda r, c: float(r.uniform(0.2, 1.0)),
    "noise_sd": lambda r, c: float(r.uniform(1.0, 3.0)),
    "vignette": lambda r, c: float(r.uniform(0.0, 0.3)),
    "camera_gain": lambda r, c: [1.0, float(np.exp(r.normal(0, 0.04)))],
    "jpeg_quality": _jpeg,
    "speed_bl_s": lambda r, c: [0.5, 1.5],
    # each fish's snout (fish_body.head_taper) and fork (its notch_power) drawn from [lo, hi]; one
    # value draws nothing
    "snout_taper": lambda r, c: [0.0, 0.0],
    "notch_power": lambda r, c: [NOTCH_POWER, NOTCH_POWER],
}


def _floor_bgr(rng) -> list[float]:
    """A tank floor: grey, blue, green or beige painted or fibreglass, a little worn."""
    base = [(190, 190, 190), (200, 160, 110), (140, 170, 120), (160, 190, 205), (110, 110, 110)]
    col = np.asarray(base[int(rng.integers(len(base)))], float) * rng.uniform(0.8, 1.15) * rng.uniform(0.95, 1.05, 3)
    return [float(v) for v in np.clip(col, 40, 240)]


def _lamps(rng) -> list[list[float]]:
    """One or two lamps ~1.5 m from the tank centre, ~45 deg above the water."""
    out = []
    for _ in range(int(rng.integers(1, 3))):
        az, el = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(38, 55))
        d = rng.uniform(800, 1800)
        out.append([float(d * np.cos(el) * np.cos(az)), float(d * np.cos(el) * np.sin(az)), float(d * np.sin(el))])
    return out


def _draw(rng, table: dict, n_fish, given: dict, setup: str) -> dict:
    unknown = sorted(set(given) - set(table))
    if unknown:
        raise ValueError(f"{setup} scene: unknown condition(s) {', '.join(unknown)}; "
                         f"known: {', '.join(table)}")
    if n_fish is not None:
        given = {**given, "n_fish": int(n_fish)}
    if given.get("clutter", "none") not in CLUTTER:
        raise ValueError(f"{setup} scene: clutter {given['clutter']!r} is not one of {', '.join(CLUTTER)}")
    bad = [k for k in ("n_fish", "bubbles", "particles") if k in given and int(given[k]) < 0]
    if bad:
        raise ValueError(f"{setup} scene: {bad[0]} must be >= 0, got {given[bad[0]]}")
    for name, bounds in SHAPE_RANGES.items():
        if name in given:
            _check_range(name, given[name], bounds, setup)
    if "species" in given and given["species"] not in SPECIES:
        raise ValueError(f"{setup} scene: unknown species {given['species']!r}; known: {', '.join(SPECIES)}")
    cond = {"setup": setup}
    for name, drawer in table.items():
        value = drawer(rng, cond)           # always drawn, so a given value keeps the others' draws
        cond[name] = given.get(name, value)
    return cond


def _texture_size(rig) -> int:
    """Texture side in texels: enough detail for the image (planes repeat mirrored beyond it)."""
    return int(np.clip(0.4 * max(rig.image_size), 160, 640))


def underwater_conditions(rng, rig, n_fish, given: dict) -> tuple[dict, dict]:
    cond = _draw(rng, UNDERWATER, n_fish, given, "underwater")
    textures = {}
    n = _texture_size(rig)
    if cond["clutter"] == "net":
        textures["net"] = net_texture(rng, mesh_mm=float(rng.uniform(20, 45)), texel_mm=4.0, size=n)
    elif cond["clutter"] == "reef":
        textures["reef"] = random_texture((n, n), rng, (1.5, 5.0, 16.0, 40.0))
    elif cond["clutter"] == "rock":
        textures["rock"] = rock_texture(rng, n)
    elif cond["clutter"] == "cage":
        mesh_mm, twine_mm = float(rng.uniform(12, 45)), float(rng.uniform(2, 6))
        angle_deg = float(rng.choice([0.0, 45.0]) + rng.normal(0, 8))     # square or diamond meshes
        textures["cage"] = cage_net_texture(rng, mesh_mm, twine_mm, angle_deg, texel_mm=2.0, size=n)
    if cond["clutter"] in ("rock", "cage"):
        cond["clutter_tone"] = _clutter_tone(rng)
        # just behind the farthest fish (range_mm's 2 m): a cage wall, a reef the fish swim along
        cond["clutter_range_mm"] = given.get("clutter_range_mm", float(rng.uniform(2050, 2800)))
    return cond, textures


# beyond these a head is a needle or a ball, a fork a hairline or a half moon
SHAPE_RANGES = {"snout_taper": (-0.5, 1.5), "notch_power": (0.5, 2.5)}


def _check_range(name: str, value, bounds: tuple[float, float], setup: str) -> None:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{setup} scene: {name} must be [lo, hi], got {value!r}") from None
    if not (bounds[0] <= lo <= hi <= bounds[1]):
        raise ValueError(f"{setup} scene: {name} {value!r} must be lo <= hi within {bounds[0]}..{bounds[1]}")


def _clutter_tone(rng) -> list[float]:
    """The backdrop's brightness against the water's (dark twine or shaded rock .. sunlit rock, a
    bright fouled net), per channel: more contrast than the drawn net and reef can have."""
    level = float(rng.choice([rng.uniform(0.1, 0.55), rng.uniform(1.3, 2.4)]))
    return [float(v) for v in level * rng.uniform(0.8, 1.2, 3)]


def surface_conditions(rng, rig, n_fish, given: dict) -> tuple[dict, dict]:
    cond = _draw(rng, SURFACE, n_fish, given, "surface")
    n = _texture_size(rig)
    floor = random_texture((n, n), rng, (2.0, 8.0, 30.0))
    textures = {"floor": (0.5 + cond["floor_texture"] * (floor - 0.5)).astype(np.float32),
                "ripples": ripple_texture(rng, n)}
    return cond, textures
