"""Simulated stereo camera for weight surveys: stereo pairs of fish with exact ground truth.

Fish are 3-D triangle meshes (laterally compressed bodies, forked caudal fin, dorsal and anal
fins; five farmed species' outlines) posed in the world frame of a calibrated rig (mm, z up,
water surface z = 0) and drawn per camera through the rig's own projection, far fish first, so
each view sees each fish in its own perspective and nearer fish hide farther ones. Truth is the
3-D snout tip and fork notch, their pixels by ``rig.project``, and flags read off the drawn masks.

Underwater (``underwater_scene``): a horizontal convergent rig at 1.5 m depth; blue-green water
brighter upwards, light falling with depth, sun shafts, turbidity (fish fade towards the water
colour with range), defocus, shades under the fish, bubbles, marine snow, a net or reef behind
some scenes. Surface (``surface_scene``): cameras 1 m above a nursery tank looking down, lamps at
~45 deg, the tank floor with the fish's shadows below, lamp glitter on the rippled water over the
fish. Both: vignetting, unequal camera gains, sensor noise, JPEG in some scenes (fish_water).
Conditions: fish_conditions; fish: fish_species, fish_body, fish_stock; where they swim:
fish_placement; drawing: fish_render, fish_paint; files: fish_io.
Ignored: refraction (at the housing port underwater, at the water surface for the surface rig:
horizontal lengths at one depth are kept to first order, only their apparent depth changes, and
the truth is stated in the unrefracted frame the rig's calibration describes), motion blur,
rolling shutter, caustics, moving ripples, lens distortion unless the rig carries it.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from devices.sim.fish_conditions import surface_conditions, underwater_conditions
from devices.sim.fish_paint import render_pair
from devices.sim.fish_placement import populate, step_swim
from devices.sim.fish_stock import Fish
from devices.sim.stereo_rig import StereoRig, convergent_rig

__all__ = ["FishTruth", "SurveyScene", "underwater_rig", "surface_rig", "underwater_scene",
           "surface_scene", "swim", "underwater_water", "still_in"]


@dataclass
class FishTruth:
    id: int                    # stable identity across frames of one swim
    species: str               # "sparus_aurata", ...
    snout_mm: np.ndarray       # (3,) world mm, snout tip (closed mouth)
    fork_mm: np.ndarray        # (3,) world mm, innermost point of the caudal fork
    length_cm: float           # |snout - fork| / 10 (fork length, 3-D)
    weight_g: float            # from the species' W = a L^b with individual scatter
    snout_px: np.ndarray       # (2, 2) [[u1, v1], [u2, v2]] true pixels (left, right)
    fork_px: np.ndarray        # (2, 2)
    measurable: bool           # snout and fork inside both images and not hidden in either
    fully_visible: bool        # whole fish inside both frames, < 10 % of it hidden in either (and measurable)
    model_weight_g: float = 0.0     # a L^b of the fork length, without the individual scatter
    hidden: tuple[float, float] = (0.0, 0.0)   # share of the fish's drawn pixels hidden (left, right)


@dataclass
class SurveyScene:
    left: np.ndarray           # (H, W, 3) uint8 BGR (colour) -- grey via cv2.cvtColor
    right: np.ndarray
    fish: list[FishTruth]
    rig: StereoRig             # rig.calibration() is the exact CALIB
    conditions: dict = field(default_factory=dict)   # what was drawn for this scene (JSON-able)


def underwater_rig(baseline_mm: float = 400.0, crossing_mm: float = 1200.0, focal_px: float = 1400.0,
                   image_size: tuple[int, int] = (1280, 960), depth_mm: float = 1500.0,
                   distortion: np.ndarray | None = None) -> StereoRig:
    """Horizontal convergent pair ``depth_mm`` under the surface looking along world +y; the axes
    cross ``crossing_mm`` ahead; fish are placed 0.6-2 m away."""
    target = np.array([0.0, crossing_mm, -depth_mm])
    return convergent_rig(baseline_mm=baseline_mm, crossing_mm=crossing_mm, focal_px=focal_px,
                          image_size=image_size, target=target, forward=np.array([0.0, 1.0, 0.0]),
                          up=np.array([0.0, 0.0, 1.0]), distortion=distortion)


def surface_rig(baseline_mm: float = 200.0, height_mm: float = 1000.0, focal_px: float = 1400.0,
                image_size: tuple[int, int] = (1280, 960), crossing_depth_mm: float = 200.0,
                distortion: np.ndarray | None = None) -> StereoRig:
    """A pair ``height_mm`` above the water looking straight down (image-up = world +y), axes
    crossing ``crossing_depth_mm`` under the surface, where the fish swim."""
    target = np.array([0.0, 0.0, -crossing_depth_mm])
    return convergent_rig(baseline_mm=baseline_mm, crossing_mm=height_mm + crossing_depth_mm,
                          focal_px=focal_px, image_size=image_size, target=target,
                          forward=np.array([0.0, 0.0, -1.0]), up=np.array([0.0, 1.0, 0.0]),
                          distortion=distortion)


def _scene(rng, rig, fishes: list[Fish], bubbles, cond: dict, textures: dict) -> SurveyScene:
    left, right, truths = render_pair(rng, rig, fishes, bubbles, cond, textures)
    return SurveyScene(left, right, [FishTruth(**t) for t in truths], rig, _public(cond))


def _public(cond: dict) -> dict:
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in cond.items()
            if not k.startswith("_")}


def underwater_scene(rng: np.random.Generator, rig: StereoRig | None = None, n_fish: int | None = None,
                     **conditions) -> SurveyScene:
    """One underwater stereo pair. ``conditions`` override what is otherwise drawn per scene from
    ``rng`` (see ``fish_conditions.UNDERWATER``); unknown names raise ValueError."""
    rig = underwater_rig() if rig is None else rig
    cond, textures = underwater_conditions(rng, rig, n_fish, conditions)
    fishes, bubbles = populate(rng, rig, cond)
    return _scene(rng, rig, fishes, bubbles, cond, textures)


def underwater_water(rng: np.random.Generator, rig: StereoRig | None = None, **conditions) -> tuple[dict, dict]:
    """The water of one camera visit (``underwater_scene``'s conditions, drawn once with their
    textures: light, turbidity, clutter, background, each camera's noise bank and glints), for
    the stills ``still_in`` draws in it: a camera held at one tank sees one water while the fish
    come and go, and the textures are half a still's rendering."""
    rig = underwater_rig() if rig is None else rig
    return underwater_conditions(rng, rig, conditions.pop("n_fish", None), conditions)


STILL_CONDITIONS = ("n_fish", "mean_length_cm", "length_cv")


def still_in(rng: np.random.Generator, rig: StereoRig, water: tuple[dict, dict], **fish) -> SurveyScene:
    """One still in ``water`` (``underwater_water``): fish placed anew (independent of the last
    still's), ``fish`` setting this still's ``STILL_CONDITIONS``; the sensor noise cut afresh."""
    unknown = sorted(set(fish) - set(STILL_CONDITIONS))
    if unknown:
        raise ValueError(f"still: {', '.join(unknown)} belong to the water, not a still; "
                         f"a still sets {', '.join(STILL_CONDITIONS)}")
    if int(fish.get("n_fish", 0)) < 0:
        raise ValueError(f"still: n_fish must be >= 0, got {fish['n_fish']}")
    cond, textures = water
    cond = {**cond, **fish}
    fishes, bubbles = populate(rng, rig, cond)
    return _scene(rng, rig, fishes, bubbles, cond, textures)


def surface_scene(rng: np.random.Generator, rig: StereoRig | None = None, n_fish: int | None = None,
                  **conditions) -> SurveyScene:
    """One stereo pair of a nursery tank seen from above (see ``fish_conditions.SURFACE``)."""
    rig = surface_rig() if rig is None else rig
    cond, textures = surface_conditions(rng, rig, n_fish, conditions)
    fishes, bubbles = populate(rng, rig, cond)
    return _scene(rng, rig, fishes, bubbles, cond, textures)


def swim(rng: np.random.Generator, setup: str, seconds: float, fps: float, rig: StereoRig | None = None,
         **conditions) -> Iterator[SurveyScene]:
    """A stereo video (``seconds * fps`` pairs): fish swim smoothly at 0.5-1.5 body lengths/s,
    turning, leaving the view and new ones (new ids) entering; ids are stable while a fish lives.
    Conditions are drawn once for the clip."""
    if setup not in ("underwater", "surface"):
        raise ValueError(f"setup: {setup!r} is neither 'underwater' nor 'surface'")
    if rig is None:
        rig = underwater_rig() if setup == "underwater" else surface_rig()
    draw = underwater_conditions if setup == "underwater" else surface_conditions
    cond, textures = draw(rng, rig, conditions.pop("n_fish", None), conditions)
    fishes, bubbles = populate(rng, rig, cond)
    for frame in range(int(round(seconds * fps))):
        if frame:
            fishes, bubbles = step_swim(rng, rig, cond, fishes, bubbles, 1.0 / fps)
        yield _scene(rng, rig, fishes, bubbles, cond, textures)
