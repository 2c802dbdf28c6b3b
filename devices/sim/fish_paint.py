"""One stereo pair: backgrounds, fish and bubbles drawn far to near per camera, noise, and truth.

Truth flags come from the drawn masks: a rank image per camera holds, per pixel, the draw order
of the fish covering it (later = nearer). A fish's snout or fork is hidden in a camera when any
nearer fish covers a pixel within ``HIDE_PX`` of it; ``hidden`` is the share of the fish's own
drawn pixels a nearer fish covers.
"""
from __future__ import annotations

import cv2
import numpy as np

from devices.sim.fish_render import SHADE_Q, Light, add_shade, draw_disc, draw_fish, project, shaded
from devices.sim.fish_water import (
    finish,
    particle_layer,
    sparkle_texture,
    surface_background,
    surface_reflections,
    underwater_background,
)

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


def _shade_points(rig, cond, posed) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per fish, the pixels (left, right) of its shade: underwater the darker water under it (its
    body dropped by about its depth), surface its shadow on the tank floor from each lamp."""
    out = []
    for p in posed:
        body = p.verts[:p.fins.min():3]            # body vertices come first, fin vertices after
        if cond["setup"] == "underwater":
            depth = np.ptp(body[:, 2])
            drop = body - [0.0, 0.0, cond["shade_drop"] * depth]
            out.append(project(rig, drop))
        else:
            floor = -cond["floor_depth_mm"]
            pts = []
            for lamp in cond["lamps"]:
                lamp = np.asarray(lamp, float)
                t = (floor - lamp[2]) / (body[:, 2] - lamp[2])
                pts.append(lamp + (body - lamp) * t[:, None])
            out.append(project(rig, np.vstack(pts)) if len(cond["lamps"]) == 1 else
                       [project(rig, q) for q in pts])
    return out


def _background(rig, cam, cond, textures):
    key = ("_bg", cam)
    if key not in textures:                       # static for a clip: drawn once
        draw = underwater_background if cond["setup"] == "underwater" else surface_background
        textures[key] = draw(rig, cam, cond, textures)
    return textures[key]


def _draw_camera(rng, rig, cam, posed, proj, shades, bubbles, bubble_px, cond, textures, light):
    background, veil = _background(rig, cam, cond, textures)
    w, h = rig.image_size
    ranks = np.zeros((h, w), np.uint8)            # draw order + 1 of the fish seen, 0: none
    c = rig.centres[cam]
    focal = (rig.K1 if cam == 0 else rig.K2)[0, 0]
    if shades and cond["shade"] > 0:
        shade_map = np.zeros(((h + SHADE_Q - 1) // SHADE_Q, (w + SHADE_Q - 1) // SHADE_Q), np.float32)
        for sh, p in zip(shades, proj, strict=True):
            extent = float(np.linalg.norm(np.ptp(p[cam], axis=0)))
            pieces = sh if isinstance(sh, list) else [sh]
            for piece in pieces:
                add_shade(shade_map, piece[cam], cond["shade"] / len(pieces), max(0.06 * extent, 1.0))
        frame = shaded(background, shade_map)
    else:
        frame = background.copy()
    if ("_sparkle", cam) not in textures:       # per camera: glints are not a shared pattern
        textures[("_sparkle", cam)] = sparkle_texture(rng, (h, w))
    sparkle = textures[("_sparkle", cam)]
    objects = [(float(np.linalg.norm(p.verts.mean(axis=0) - c)), 0, i) for i, p in enumerate(posed)]
    objects += [(float(np.linalg.norm(b[:3] - c)), 1, j) for j, b in enumerate(bubbles)]
    objects.sort(key=lambda o: -o[0])
    rank_of, drawn = {}, {}
    for dist, kind, i in objects:
        blur = cond["blur_gain"] * abs(dist - cond["focus_mm"]) / dist
        if kind == 0:
            rank_of[i] = len(rank_of)
            drawn[i] = draw_fish(frame, ranks, rank_of[i] + 1, posed[i], proj[i][cam], c, light, veil,
                                 cond["visibility_mm"], blur, sparkle)
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
        surface_reflections(frame, rig, cam, cond, textures)
    elif cond["particles"]:
        key = ("_snow", cam)
        if key not in textures:                   # the snow hangs still over a clip
            snow = _snow(rng, rig, cond)
            textures[key] = particle_layer((h, w), project(rig, snow)[cam], np.linalg.norm(snow - c, axis=1),
                                           veil, cond["visibility_mm"])
        idx, add = textures[key]
        frame[idx] += add
    return finish(frame, cam, cond, rng, textures), ranks, rank_of, drawn


def _snow(rng, rig, cond) -> np.ndarray:
    """World points of the marine snow in front of the rig (0.2-3 m), fixed for a clip (the same
    points for both cameras: drawn from a generator seeded by the scene)."""
    rng = np.random.default_rng(cond["_snow_seed"])
    n = int(cond["particles"])
    w, h = rig.image_size
    uv = rng.uniform([-0.1 * w, -0.1 * h], [1.1 * w, 1.1 * h], (n, 2))
    rays = np.c_[uv, np.ones(n)] @ np.linalg.inv(rig.K1).T @ rig.R1
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    return rig.centres[0] + rays * rng.uniform(200, 3000, (n, 1))


def _covered(ranks: np.ndarray, px: np.ndarray, rank: int) -> bool:
    """A fish drawn after the one of draw order ``rank`` covers a pixel within HIDE_PX of px."""
    h, w = ranks.shape
    u, v = int(round(px[0])), int(round(px[1]))
    win = ranks[max(v - HIDE_PX, 0):min(v + HIDE_PX + 1, h), max(u - HIDE_PX, 0):min(u + HIDE_PX + 1, w)]
    return bool(win.size and np.any(win > rank + 1))


def render_pair(rng, rig, fishes, bubbles, cond, textures, masks: bool = False):
    """(left, right, truth dicts) for the scene's fish; with ``masks`` also, per camera, a (H, W)
    int array holding the index (in ``fishes``) of the fish seen at each pixel, -1 for none."""
    if len(fishes) > 254:
        raise ValueError(f"n_fish: {len(fishes)} fish in one scene; at most 254")
    light = scene_light(rig, cond)
    posed = [f.posed() for f in fishes]
    for p in posed:
        p.gain *= cond["fish_gain"]
    proj = [project(rig, p.verts) for p in posed]
    shades = _shade_points(rig, cond, posed)
    bubble_px = project(rig, bubbles[:, :3])
    images, ranks, rank_of, drawn = [], [], [], []
    for cam in (0, 1):
        img, rk, ro, dr = _draw_camera(rng, rig, cam, posed, proj, shades, bubbles, bubble_px, cond,
                                       textures, light)
        images.append(img)
        ranks.append(rk)
        rank_of.append(ro)
        drawn.append(dr)
    counts = [cv2.calcHist([rk], [0], None, [256], [0, 256]).ravel()[1:] for rk in ranks]
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
            seen = counts[cam][rank_of[cam][i]]
            hidden.append(1.0 - seen / d.pixels if d.pixels else 1.0)
            whole = whole and d.inside and d.pixels > 0
            if inside:
                clear = clear and not any(_covered(ranks[cam], q, rank_of[cam][i]) for q in p)
        truths.append(dict(
            id=f.id, species=f.species.name, snout_mm=snout, fork_mm=fork,
            length_cm=float(np.linalg.norm(snout - fork) / 10.0), weight_g=f.weight_g,
            snout_px=np.array([p1[0], p2[0]]), fork_px=np.array([p1[1], p2[1]]),
            measurable=bool(inside and clear),
            fully_visible=bool(inside and clear and whole and max(hidden) < FULLY_VISIBLE_HIDDEN),
            model_weight_g=float(f.species.a * (f.length_mm / 10.0) ** f.species.b),
            hidden=(float(hidden[0]), float(hidden[1]))))
    if masks:
        seen = []
        for cam in (0, 1):
            lut = np.full(256, -1, np.int64)
            for i, r in rank_of[cam].items():
                lut[r + 1] = i
            seen.append(lut[ranks[cam]])
        return images[0], images[1], truths, seen
    return images[0], images[1], truths
