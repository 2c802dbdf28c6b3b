"""A fish as a 3-D triangle mesh: a laterally compressed body plus thin fins in its mid-plane.

Fish frame (mm): x from the snout tip (x = 0) back towards the tail, the fork notch at x = L
(fork length); y to the fish's right; z to its back (a right-handed frame). The body is a ring of elliptical cross
sections (half height above / below the snout-fork axis, half width) collapsing to the snout tip;
the caudal fin is a forked plate whose innermost trailing-edge point is (L, 0, 0) exactly. A
lateral bend (circular arc of curvature ``bend``, 1/mm) keeps arc length, so the 3-D snout-fork
distance is the chord, slightly under L, as a stereo rig would measure it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from devices.sim.fish_species import Species

N_ALONG, N_AROUND = 36, 18
NOTCH_POWER = 1.3    # the species' forks: a narrowing slit at the notch (``_caudal_outline``)


def _profile(u: np.ndarray, at: float, end: float, p: float = 0.66) -> np.ndarray:
    """Depth or width profile along the body, 0 at the snout, 1 at its maximum, ``end`` at u = 1."""
    q = p * (1 - at) / at                           # puts the maximum of u^p (1-u)^q at ``at``
    f = np.power(u, p) * np.power(1 - u, q)
    f /= at ** p * (1 - at) ** q
    blend = np.clip((u - at) / (1 - at), 0, 1) ** 2
    return np.maximum(f, 0) * (1 - blend) + blend * np.maximum(f, end)


@dataclass
class FishMesh:
    """Fish-frame vertices (N, 3), body faces (M, 3), fin faces (K, 3) indexing the same vertices,
    per-vertex ``belly`` (0 back .. 1 belly) and ``along`` (0 snout .. 1 peduncle)."""

    verts: np.ndarray
    body: np.ndarray
    fins: np.ndarray
    belly: np.ndarray
    along: np.ndarray
    length_mm: float
    fork_vertex: int = 0           # index of the vertex at the fork notch (L, 0, 0)


def build_mesh(sp: Species, length_mm: float, shape_jitter: np.ndarray | None = None,
               fork_scale: float = 1.0, wear: float = 0.0, rng: np.random.Generator | None = None,
               snout_taper: float = 0.0, notch_power: float = NOTCH_POWER) -> FishMesh:
    """Mesh of one fish of fork length ``length_mm``. ``shape_jitter`` (3,) scales depth, width and
    fin size of this individual (1 = the species' outline); ``fork_scale`` the depth of its fork;
    ``wear`` (0..1, needs ``rng``) frays the caudal fin's trailing edge as fin erosion does in
    farmed fish, at most half way to the notch, which stays the innermost point. ``snout_taper``
    reshapes the head alone (``head_taper``): > 0 a more pointed snout, < 0 a blunter one;
    ``notch_power`` the caudal fork's shape (``_caudal_outline``)."""
    jd, jw, jf = (1.0, 1.0, 1.0) if shape_jitter is None else shape_jitter
    L = length_mm
    x_end = sp.body_end * L
    u = np.linspace(0, 1, N_ALONG + 1)[1:] ** 1.4                   # denser at the head
    depth = sp.depth * jd * L * _profile(u, sp.depth_at, sp.peduncle)
    width = 0.5 * sp.width * jw * L * _profile(u, sp.depth_at * 0.9, 0.25, 0.65)
    if snout_taper:
        taper = head_taper(u, snout_taper)
        depth, width = depth * taper, width * taper
    up = depth * sp.dorsal_share
    down = depth * (1 - sp.dorsal_share)
    th = np.linspace(0, 2 * np.pi, N_AROUND, endpoint=False)       # 0 = dorsal, pi = ventral
    c, s = np.cos(th), np.sin(th)
    z = np.where(c[None] >= 0, up[:, None], down[:, None]) * c[None]
    y = width[:, None] * s[None]
    x = np.broadcast_to((u * x_end)[:, None], z.shape)
    ring = np.stack([x, y, z], -1).reshape(-1, 3)
    verts = [np.zeros((1, 3)), ring]
    belly = [np.array([0.5]), np.broadcast_to((1 - c[None]) / 2, z.shape).ravel()]
    along = [np.array([0.0]), np.broadcast_to(u[:, None], z.shape).ravel()]
    body = _BODY_FACES
    base = 1 + N_ALONG * N_AROUND
    # fins: closed outlines in the x-z mid-plane, fanned from an inner point
    outlines = [_caudal_outline(sp, L, up[-1], down[-1], jf, fork_scale, wear, rng, notch_power)]
    for (start, stop, height), sign, prof in ((sp.dorsal_fin, 1, up), (sp.anal_fin, -1, down)):
        outlines.append(_median_fin_outline(u, prof, start, stop, height * jf * L, sign, x_end))
    fin_faces, fin_verts = [], []
    n = base
    for outline, centre in outlines:
        k = len(outline)
        fin_verts += [centre[None], outline]
        idx = n + 1 + np.arange(k)
        fin_faces.append(np.c_[np.full(k - 1, n), idx[:-1], idx[1:]])
        n += k + 1
    fv = np.vstack(fin_verts)
    fv = np.c_[fv[:, 0], np.zeros(len(fv)), fv[:, 1]]
    verts = np.vstack(verts + [fv])
    belly = np.concatenate(belly + [np.full(len(fv), 0.5)])
    along = np.concatenate(along + [np.clip(fv[:, 0] / x_end, 0, 1)])
    fork = int(np.argmin(np.linalg.norm(verts - [L, 0.0, 0.0], axis=1)))
    return FishMesh(verts, body, np.vstack(fin_faces), belly, along, L, fork)


HEAD = 0.2     # the share of the body (snout = 0) a snout's taper reshapes


def head_taper(u: np.ndarray, taper: float) -> np.ndarray:
    """Factor on the body's depth and width along it (u: 0 snout .. 1 peduncle): (u / HEAD)^taper over
    the head, 1 behind it, so the snout's outline goes as u^(0.66 + taper) (a cone at ~0.34, a
    rounded head below 0.66) while the body keeps its species' outline."""
    return np.minimum(np.asarray(u, float) / HEAD, 1.0) ** taper


def _body_faces() -> np.ndarray:
    """Body triangles (same for every fish): a fan at the snout, two per quad between rings,
    wound so their normals point out of the body (the ring runs dorsal -> right -> ventral)."""
    j = np.arange(N_AROUND)
    jn = (j + 1) % N_AROUND
    faces = [np.stack([np.zeros(N_AROUND, int), 1 + jn, 1 + j], 1)]
    i = np.arange(N_ALONG - 1)[:, None]
    a, b = 1 + i * N_AROUND, 1 + (i + 1) * N_AROUND
    faces.append(np.stack([a + j, a + jn, b + j], -1).reshape(-1, 3))
    faces.append(np.stack([a + jn, b + jn, b + j], -1).reshape(-1, 3))
    faces = np.vstack(faces)
    # orientation from a reference ellipsoid-like body (the parameterisation fixes it for all)
    u = np.linspace(0, 1, N_ALONG + 1)[1:]
    th = np.linspace(0, 2 * np.pi, N_AROUND, endpoint=False)
    r = np.sin(np.pi * np.sqrt(u))[:, None]
    ring = np.stack([np.broadcast_to(u[:, None], (N_ALONG, N_AROUND)), 0.3 * r * np.sin(th), r * np.cos(th)], -1)
    return _outward(np.vstack([np.zeros((1, 3)), ring.reshape(-1, 3)]), faces)


def _outward(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces wound so their normals point away from the snout-fork axis (for back-face culling)."""
    a, b, c = (verts[faces[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    centroid = (a + b + c) / 3
    out = centroid - np.c_[centroid[:, 0], np.zeros((len(faces), 2))]
    out[:, 0] = 0.0
    flip = np.einsum("ij,ij->i", n, out) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    return faces


_BODY_FACES = _body_faces()


def _caudal_outline(sp: Species, L: float, top: float, bottom: float, jf: float, fork_scale: float = 1.0,
                    wear: float = 0.0, rng: np.random.Generator | None = None, notch_power: float = NOTCH_POWER):
    """(x, z) outline of the forked caudal fin, from the peduncle's top round to its bottom, and
    the fan centre. The trailing edge runs lobe tip -> notch (L, 0) -> lobe tip, concave; near the
    notch it is x - L ~ |z|^(1 / notch_power): a slit over 1, a V at 1, a rounded U under it."""
    x0 = sp.body_end * L
    tip_x = L + (sp.lobe_tip - 1.0) * L * jf * fork_scale
    span = sp.lobe_span * L * jf
    t = np.linspace(0, 1, 8)
    # leading (outer) edge: peduncle corner to the tip, bulging outwards
    lead_x = x0 + (tip_x - x0) * t
    lead_z = top + (span - top) * t ** 0.7
    # trailing edge: tip to notch, a concave curve (the fork)
    trail_x = tip_x + (L - tip_x) * t[1:]
    trail_z = span * (1 - t[1:]) ** notch_power
    upper = np.c_[np.r_[lead_x, trail_x], np.r_[lead_z, trail_z]]
    lower = upper[::-1][1:] * [1, -1]
    if wear > 0 and rng is not None:
        n = len(t) - 1                                # trailing-edge points before the notch
        for part, idx in ((upper, np.arange(len(t) - 1, len(t) - 1 + n - 1)), (lower, np.arange(1, n))):
            from_notch = np.abs(part[idx, 1]) / max(span, 1e-9)
            bite = wear * rng.uniform(0, 1, len(idx)) * 0.35 * (tip_x - x0) * from_notch
            part[idx, 0] = np.maximum(part[idx, 0] - bite, L + 0.5 * (part[idx, 0] - L))
    lower[:, 1] *= bottom / top if top > 0 else 1.0
    outline = np.vstack([upper, lower])
    centre = np.array([x0 - 0.02 * L, 0.0])
    return outline, centre


def _median_fin_outline(u, prof, start, stop, height, sign, x_end):
    """(x, z) outline of a dorsal (sign +1) or anal (-1) fin standing on the body profile."""
    t = np.linspace(start, stop, 9)
    base_z = np.interp(t, u, prof) * 0.85
    rise = height * np.sin(np.pi * (t - start) / (stop - start)) ** 0.6 * (1 - 0.5 * (t - start) / (stop - start))
    x = t * x_end
    outer = np.c_[x + 0.3 * rise, base_z + rise]
    inner = np.c_[x, base_z][::-1]
    outline = np.vstack([inner[-1:], outer, inner]) * [1, sign]
    centre = np.array([x.mean(), sign * base_z.mean() * 0.9])
    return outline, centre


def bend(points: np.ndarray, curvature: float) -> np.ndarray:
    """Bend fish-frame points sideways along a circular arc (arc length kept along x)."""
    if abs(curvature) < 1e-12:
        return points.copy()
    x, y, z = points.T
    a = curvature * x
    cx, cy = np.sin(a) / curvature, (1 - np.cos(a)) / curvature
    return np.stack([cx - y * np.sin(a), cy + y * np.cos(a), z], axis=1)


def pose_matrix(heading_rad: float, pitch_rad: float, roll_rad: float) -> np.ndarray:
    """World <- fish rotation (columns: fish x, y, z in world). The snout points along heading
    (from world +x towards +y) raised by pitch; fish x runs snout -> tail, so it is minus that."""
    ch, shh = np.cos(heading_rad), np.sin(heading_rad)
    cp, sp_ = np.cos(pitch_rad), np.sin(pitch_rad)
    forward = np.array([ch * cp, shh * cp, sp_])
    left = np.array([-shh, ch, 0.0])
    dorsal = np.cross(forward, left)
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    left, dorsal = cr * left + sr * dorsal, -sr * left + cr * dorsal
    return np.c_[-forward, -left, dorsal]

