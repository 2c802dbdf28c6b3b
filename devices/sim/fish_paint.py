"""One stereo pair: backgrounds, fish and bubbles drawn far to near per camera, noise, and truth.

Truth flags come from the drawn masks: a rank image per camera holds, per pixel, the draw order
of the fish covering it (later = nearer). A fish's snout or fork is hidden in a camera when any
nearer fish covers a pixel within ``HIDE_PX`` of it; ``hidden`` is the share of the fish's own
drawn pixels a nearer fish covers.
"""
from __future__ import annotations

import numpy as np

from devices.sim.fish_render import Light, draw_disc, draw_fish, project
from devices.sim.fish_water import add_noise, surface_background, surface_reflections, underwater_background

HIDE_PX = 2                        # a point this close to a nearer fish's outline counts as hidden
FULLY_VISIBLE_HIDDEN = 0.10


def scene_light(rig, cond: dict) -> Light:
    colour = np.asarray(cond["light_bgr"], float)
    if cond["setup"] == "underwater":
        t, a = np.radians(cond["sun_tilt_deg"]), np.radians(cond["sun_azimuth_deg"])
        d = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])
        return Light(d, colour, cond["ambient"], cond["light_attenuation_mm"], z_ref=float(rig.target[2]))
    d = np.sum([np.asarray(p, float) / np.linalg.norm(p) for p in cond["lamps"]], axis=0)
    return Light(d / np.linalg.norm(d), colour, cond["ambient"], 1e12, z_ref=0.0, shininess=20.0)


def _draw_camera(rng, rig, cam, posed, proj, bubbles, bubble_px, cond, textures, light):
    background = underwater_background if cond["setup"] == "underwater" else surface_background
    frame, veil = background(rig, cam, cond, textures)
    w, h = rig.image_size
    ranks = np.full((h, w), -1, np.int16)
    c = rig.centres[cam]
    focal = (rig.K1 if cam == 0 else rig.K2)[0, 0]
    objects = [(float(np.linalg.norm(p.verts.mean(axis=0) - c)), 0, i) for i, p in enumerate(posed)]
    objects += [(float(np.linalg.norm(b[:3] - c)), 1, j) for j, b in enumerate(bubbles)]
    objects.sort(key=lambda o: -o[0])
    rank_of, drawn = {}, {}
    for dist, kind, i in objects:
        blur = cond["blur_gain"] * abs(dist - cond["focus_mm"]) / dist
        if kind == 0:
            rank_of[i] = len(rank_of)
            drawn[i] = draw_fish(frame, ranks, rank_of[i], posed[i], proj[i][cam], c, light, veil,
                                 cond["visibility_mm"], blur)
        else:
            u, v = bubble_px[cam][i]
            if not (-20 < u < w + 20 and -20 < v < h + 20):
                continue
            trans = np.exp(-dist / cond["visibility_mm"])
            vi, ui = int(np.clip(v, 0, h - 1)), int(np.clip(u, 0, w - 1))
            col = veil[vi, ui] * 1.5 + 50.0
            draw_disc(frame, None, 0, np.array([u, v]), focal * bubbles[i, 3] / dist + blur,
                      col, 0.8 * trans + 0.1)
    if cond["setup"] == "surface":
        surface_reflections(frame, rig, cam, cond, textures["ripples"])
    return add_noise(frame, cond["noise_sd"], rng), ranks, rank_of, drawn


def _covered(ranks: np.ndarray, px: np.ndarray, rank: int) -> bool:
    h, w = ranks.shape
    u, v = int(round(px[0])), int(round(px[1]))
    win = ranks[max(v - HIDE_PX, 0):min(v + HIDE_PX + 1, h), max(u - HIDE_PX, 0):min(u + HIDE_PX + 1, w)]
    return bool(win.size and np.any(win > rank))


def render_pair(rng, rig, fishes, bubbles, cond, textures, masks: bool = False):
    """(left, right, truth dicts) for the scene's fish; with ``masks`` also, per camera, a (H, W)
    int array holding the index (in ``fishes``) of the fish seen at each pixel, -1 for none."""
    light = scene_light(rig, cond)
    posed = [f.posed() for f in fishes]
    proj = [project(rig, p.verts) for p in posed]
    bubble_px = project(rig, bubbles[:, :3])
    images, ranks, rank_of, drawn = [], [], [], []
    for cam in (0, 1):
        img, rk, ro, dr = _draw_camera(rng, rig, cam, posed, proj, bubbles, bubble_px, cond, textures, light)
        images.append(img)
        ranks.append(rk)
        rank_of.append(ro)
        drawn.append(dr)
    counts = [np.bincount(rk.ravel().astype(np.int64) + 1, minlength=len(fishes) + 1)[1:] for rk in ranks]
    w, h = rig.image_size
    truths = []
    for i, f in enumerate(fishes):
        snout, fork = f.snout_fork()
        p1, p2 = project(rig, np.array([snout, fork]))
        z1, z2 = rig.depths(np.array([snout, fork]))
        inside = all(np.all((p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1))
                     for p in (p1, p2)) and np.all(z1 > 0) and np.all(z2 > 0)
        hidden, whole, clear = [], True, True
        for cam, p in ((0, p1), (1, p2)):
            d = drawn[cam][i]
            seen = counts[cam][rank_of[cam][i]] if rank_of[cam][i] < len(counts[cam]) else 0
            hidden.append(1.0 - seen / d.pixels if d.pixels else 1.0)
            whole = whole and d.inside and d.pixels > 0
            if inside:
                clear = clear and not any(_covered(ranks[cam], q, rank_of[cam][i]) for q in p)
        truths.append(dict(
            id=f.id, species=f.species.name, snout_mm=snout, fork_mm=fork,
            length_cm=float(np.linalg.norm(snout - fork) / 10.0), weight_g=f.weight_g,
            snout_px=np.array([p1[0], p2[0]]), fork_px=np.array([p1[1], p2[1]]),
            measurable=bool(inside and clear),
            fully_visible=bool(whole and max(hidden) < FULLY_VISIBLE_HIDDEN),
            model_weight_g=float(f.species.a * (f.length_mm / 10.0) ** f.species.b),
            hidden=(float(hidden[0]), float(hidden[1]))))
    if masks:
        seen = []
        for cam in (0, 1):
            lut = np.full(len(fishes) + 1, -1, np.int64)
            for i, r in rank_of[cam].items():
                lut[r + 1] = i
            seen.append(lut[ranks[cam].astype(np.int64) + 1])
        return images[0], images[1], truths, seen
    return images[0], images[1], truths
