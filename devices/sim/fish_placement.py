"""Where the fish of a scene are, and how they swim from frame to frame.

Underwater: fish centres anywhere in the left camera's view (and ``frame_margin`` beyond its
edges, so some are cut by the frame) at 0.6-2 m; headings mostly side-on to the line of sight,
``yaw_sd_deg`` off it (at most ``max_yaw_deg``), pitch and roll small, a slight lateral bend.
Surface: fish at ``swim_depth_mm`` under the surface, any heading. No two bodies intersect.
Swimming: speed 0.5-1.5 body lengths/s, a smoothly wandering turn rate (underwater pulled back
towards side-on, as fish circling a cage pass the cameras), a tail beat; a fish that leaves the
view volume is replaced by a new one (new id) entering from a side.
"""
from __future__ import annotations

import numpy as np

from devices.sim.fish_species import SPECIES
from devices.sim.fish_stock import Fish, clear_of, make_fish, segment_distance

TRIES = 40


def _ray(rig, u: float, v: float) -> np.ndarray:
    d = rig.R1.T @ np.linalg.solve(rig.K1, np.array([u, v, 1.0]))
    return d / np.linalg.norm(d)


def _pixel(rig, cond, rng, edge: int = 0) -> tuple[float, float]:
    """A pixel of the left image's extended frame; ``edge`` -1/+1 puts it on the left/right rim."""
    w, h = rig.image_size
    m = cond["frame_margin"]
    u = rng.uniform(-m * w, (1 + m) * w) if edge == 0 else (-m * w if edge < 0 else (1 + m) * w)
    return u, rng.uniform(-m * h, (1 + m) * h)


def _side_on(rig, fish: Fish) -> float:
    """Heading (rad) of the line of sight from the left camera to the fish."""
    d = fish.centre - rig.centres[0]
    return float(np.arctan2(d[1], d[0]))


def _pose(rng, rig, cond, fish: Fish, edge: int = 0) -> bool:
    L = fish.length_mm
    u, v = _pixel(rig, cond, rng, edge)
    if cond["setup"] == "underwater":
        fish.centre = rig.centres[0] + _ray(rig, u, v) * rng.uniform(*cond["range_mm"])
        if fish.centre[2] > -0.5 * L:
            return False
        off = np.clip(rng.normal(0, cond["yaw_sd_deg"]), -cond["max_yaw_deg"], cond["max_yaw_deg"])
        side = rng.choice([-1.0, 1.0])
        fish.heading = _side_on(rig, fish) + side * np.pi / 2 + np.radians(off)
    else:
        d = _ray(rig, u, v)
        z = -rng.uniform(*cond["swim_depth_mm"])
        c = rig.centres[0]
        fish.centre = c + d * (z - c[2]) / d[2]
        fish.heading = rng.uniform(-np.pi, np.pi)
    if edge:
        _head_inwards(rig, cond, fish, rng)
    mp, mr = np.radians(cond["max_pitch_deg"]), np.radians(cond["max_roll_deg"])
    fish.pitch = float(np.clip(rng.normal(0, mp / 2.5), -mp, mp))
    fish.roll = float(np.clip(rng.normal(0, mr / 2.5), -mr, mr))
    fish.bend_amp = abs(rng.normal(0, cond["bend"])) * 2 / L + 1e-9
    fish.beat_phase = rng.uniform(0, 2 * np.pi)
    fish.curvature = fish.bend_amp * np.sin(fish.beat_phase)
    fish.speed_mm_s = rng.uniform(*cond["speed_bl_s"]) * L
    fish.turn_rad_s = 0.0
    return True


def _head_inwards(rig, cond, fish: Fish, rng) -> None:
    """Turn a fish placed on the rim so it swims into the view."""
    inward = np.asarray(rig.target, float) - fish.centre
    if cond["setup"] == "surface":
        fish.heading = float(np.arctan2(inward[1], inward[0]) + rng.normal(0, 0.5))
    elif np.cos(fish.heading) * inward[0] + np.sin(fish.heading) * inward[1] < 0:
        fish.heading += np.pi


def _length_mm(rng, cond) -> float:
    mean = cond["mean_length_cm"]
    return 10.0 * max(0.5 * mean, rng.normal(mean, cond["length_cv"] * mean))


SHAPES = ("snout_taper", "notch_power")     # conditions drawn per fish from [lo, hi]


def _per_fish(rng, bounds) -> float:
    lo, hi = bounds
    return float(rng.uniform(lo, hi)) if hi > lo else float(lo)     # one value draws nothing: seeds keep their fish


def _new_fish(rng, rig, cond, fid: int, others: list[Fish], edge: int = 0) -> Fish | None:
    sp = SPECIES[cond["species"]]
    shape = {name: _per_fish(rng, cond[name]) for name in SHAPES}
    fish = make_fish(rng, fid, sp, _length_mm(rng, cond), cond["weight_scatter"], **shape)
    for _ in range(TRIES):
        if _pose(rng, rig, cond, fish, edge) and clear_of(fish, others):
            return fish
    return None


def populate(rng, rig, cond) -> tuple[list[Fish], np.ndarray]:
    """The scene's fish (ids 0..) and bubbles (n, 4: x, y, z, radius mm)."""
    fishes: list[Fish] = []
    for i in range(cond["n_fish"]):
        f = _new_fish(rng, rig, cond, i, fishes)
        if f is not None:
            fishes.append(f)
    cond["_next_id"] = cond["n_fish"]
    return fishes, _bubbles(rng, rig, cond, cond["bubbles"])


def _bubbles(rng, rig, cond, n: int) -> np.ndarray:
    out = np.zeros((n, 4))
    for k in range(n):
        u, v = _pixel(rig, cond, rng)
        d = _ray(rig, u, v)
        if cond["setup"] == "underwater":
            out[k, :3] = rig.centres[0] + d * rng.uniform(350, 2600)
        else:
            c = rig.centres[0]
            z = -rng.uniform(5, cond["floor_depth_mm"] * 0.8)
            out[k, :3] = c + d * (z - c[2]) / d[2]
        out[k, 3] = rng.uniform(0.4, 3.0)
    return out


def _in_volume(rig, cond, fish: Fish) -> bool:
    w, h = rig.image_size
    m = cond["frame_margin"] + 0.05
    p = rig.P1 @ np.r_[fish.centre, 1.0]
    if p[2] <= 0:
        return False
    u, v = p[:2] / p[2]
    if not (-m * w <= u <= (1 + m) * w and -m * h <= v <= (1 + m) * h):
        return False
    if cond["setup"] == "underwater":
        r = np.linalg.norm(fish.centre - rig.centres[0])
        lo, hi = cond["range_mm"]
        return 0.85 * lo <= r <= 1.1 * hi and fish.centre[2] < -0.3 * fish.length_mm
    lo, hi = cond["swim_depth_mm"]
    return -hi - 20 <= fish.centre[2] <= -lo + 20


def step_swim(rng, rig, cond, fishes: list[Fish], bubbles: np.ndarray, dt: float):
    """Advance every fish and bubble by ``dt`` seconds; replace fish that left."""
    kept: list[Fish] = []
    for f in fishes:
        tau, sigma = 1.5, 0.5                             # s, rad/s: smooth wandering turns
        f.turn_rad_s += -f.turn_rad_s * dt / tau + sigma * np.sqrt(2 * dt / tau) * rng.normal()
        if cond["setup"] == "underwater":                 # pulled towards side-on
            side = _side_on(rig, f)
            err = np.angle(np.exp(1j * (f.heading - side)))
            target = np.sign(err) * np.pi / 2 if err != 0 else np.pi / 2
            f.heading += -0.3 * np.angle(np.exp(1j * (err - target))) * dt
        f.heading += f.turn_rad_s * dt
        f.pitch += (-f.pitch * dt / 2.0) + 0.05 * np.sqrt(dt) * rng.normal()
        R = f.rotation()
        f.centre = f.centre + (-R[:, 0]) * f.speed_mm_s * dt
        f.beat_phase += 2 * np.pi * (1.0 + f.speed_mm_s / f.length_mm) * dt
        f.curvature = f.bend_amp * np.sin(f.beat_phase)
    _keep_apart(fishes, dt)
    for f in fishes:
        if _in_volume(rig, cond, f):
            kept.append(f)
    while len(kept) < cond["n_fish"]:
        new = _new_fish(rng, rig, cond, cond["_next_id"], kept, edge=int(rng.choice([-1, 1])))
        cond["_next_id"] += 1
        if new is None:
            break
        kept.append(new)
    if len(bubbles):
        bubbles = bubbles.copy()
        bubbles[:, 2] += (150 + 60 * bubbles[:, 3]) * dt
        bubbles[:, 0] += 20 * rng.normal(size=len(bubbles)) * dt
        gone = ~_bubbles_in(rig, cond, bubbles)
        if gone.any():
            bubbles[gone] = _bubbles(rng, rig, cond, int(gone.sum()))
    return kept, bubbles


def _keep_apart(fishes: list[Fish], dt: float) -> None:
    """Fish about to touch turn away from each other; bodies that would still overlap are eased
    apart (a few mm a frame), so drawn fish never pass through one another."""
    for i, a in enumerate(fishes):
        for b in fishes[i + 1:]:
            d = a.centre - b.centre
            dist = float(np.linalg.norm(d))
            if dist > 0.6 * (a.length_mm + b.length_mm) or dist == 0.0:
                continue
            sa, fa, ra = a.segment_radius()
            sb, fb, rb = b.segment_radius()
            gap = segment_distance(sa, fa, sb, fb)
            need = 0.9 * (ra + rb)
            if gap > 1.5 * need:
                continue
            away = d / dist
            for fish, sign in ((a, 1.0), (b, -1.0)):
                fwd = np.array([np.cos(fish.heading), np.sin(fish.heading)])
                side = fwd[0] * away[1] - fwd[1] * away[0]     # > 0: away is to the fish's left
                fish.heading += sign * np.sign(side) * 1.5 * dt
            if gap < need:
                push = away * (need - gap) / 2
                a.centre = a.centre + push
                b.centre = b.centre - push


def _bubbles_in(rig, cond, bubbles: np.ndarray) -> np.ndarray:
    p = np.c_[bubbles[:, :3], np.ones(len(bubbles))] @ rig.P1.T
    v = p[:, 1] / p[:, 2]
    h = rig.image_size[1]
    top = bubbles[:, 2] < -5
    return (p[:, 2] > 0) & (v > -0.2 * h) & top
