"""The fish a scene holds: sizes from a stock, weights from W = a L^b, skin, and poses in view.

Lengths: normal around the stock mean with the stock's coefficient of variation. Weights: the
species' a L^b times a lognormal condition factor (mean 1, ``weight_scatter`` its sd in log),
so fish of one length differ in weight as farmed fish do. Skin: countershading from back to belly,
mottled scale texture and species markings fixed to the body (both cameras see the same skin).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from devices.sim.fish_body import FishMesh, bend, build_mesh, pose_matrix
from devices.sim.fish_render import Posed
from devices.sim.fish_species import Species


@dataclass
class Fish:
    id: int
    species: Species
    length_mm: float               # fork length along the (unbent) body
    weight_g: float
    mesh: FishMesh
    face_albedo: np.ndarray        # (M, 3) BGR per body face
    glint: np.ndarray              # (M,) per body face
    fin_alpha: float
    centre: np.ndarray             # (3,) world mm, mid-body on the axis
    heading: float
    pitch: float
    roll: float
    curvature: float               # lateral bend, 1/mm
    speed_mm_s: float = 0.0        # swimming state (swim only)
    turn_rad_s: float = 0.0
    beat_phase: float = 0.0
    bend_amp: float = 0.0          # curvature amplitude of the tail beat, 1/mm
    gain: float = 1.0              # brightness of this fish under the scene's light
    scales: float = 30.0           # rows of the scale lattice along the body
    scale_contrast: float = 0.08
    fin_rays: float = 30.0         # fin rays across the caudal fin
    ray_contrast: float = 0.1
    # (pose, (snout, fork, radius)): placing a scene's fish checks each new one against every one
    # placed, up to 40 tries each: the placed fish's segments, posed anew each time, were ~10 % of
    # a rendered still
    _segment: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def rotation(self) -> np.ndarray:
        return pose_matrix(self.heading, self.pitch, self.roll)

    def _place(self, local: np.ndarray) -> np.ndarray:
        R = self.rotation()
        mid = bend(np.array([[self.length_mm / 2, 0.0, 0.0]]), self.curvature)[0]
        return self.centre + (bend(local, self.curvature) - mid) @ R.T

    def snout_fork(self) -> tuple[np.ndarray, np.ndarray]:
        pts = self._place(np.array([[0.0, 0.0, 0.0], [self.length_mm, 0.0, 0.0]]))
        return pts[0], pts[1]

    def posed(self) -> Posed:
        return Posed(self._place(self.mesh.verts), self.mesh.body, self.mesh.fins, self.face_albedo,
                     np.asarray(self.species.fin, float), self.glint, self.fin_alpha,
                     self.mesh.fork_vertex, self.gain, self.scales, self.scale_contrast, None,
                     self.fin_rays, self.ray_contrast)

    def segment_radius(self) -> tuple[np.ndarray, np.ndarray, float]:
        pose = (self.centre.tobytes(), self.heading, self.pitch, self.roll, self.curvature, self.length_mm)
        if self._segment is None or self._segment[0] != pose:
            s, f = self.snout_fork()
            self._segment = (pose, (s, f, 0.5 * self.species.depth * self.length_mm))
        return self._segment[1]


def make_fish(rng: np.random.Generator, fid: int, sp: Species, length_mm: float,
              weight_scatter: float, **shape) -> Fish:
    """One fish of species ``sp`` (pose to be set by the caller; ``shape``: ``build_mesh``'s
    ``snout_taper``, ``notch_power``)."""
    jitter = 1.0 + rng.normal(0, [0.04, 0.05, 0.08])
    wear = float(rng.uniform(0.2, 1.0)) if rng.random() < 0.4 else 0.0      # eroded caudal fins
    mesh = build_mesh(sp, length_mm, jitter, fork_scale=float(np.exp(rng.normal(0, 0.12))), wear=wear, rng=rng,
                      **shape)
    L_cm = length_mm / 10.0
    k = np.exp(rng.normal(-0.5 * weight_scatter ** 2, weight_scatter)) if weight_scatter > 0 else 1.0
    weight = sp.a * L_cm ** sp.b * k
    albedo = _skin(rng, sp, mesh)[mesh.body].mean(axis=1)
    glint = np.where(rng.random(len(mesh.body)) < 0.35, rng.uniform(0.3, 1.4, len(mesh.body)), 0.0)
    glint *= 255.0 * rng.uniform(0.3, 1.0)
    return Fish(fid, sp, length_mm, float(weight), mesh, albedo, glint, float(rng.uniform(0.35, 0.75)),
                np.zeros(3), 0.0, 0.0, 0.0, 0.0, gain=float(np.exp(rng.normal(0, 0.15))),
                scales=float(rng.uniform(25, 40)), scale_contrast=float(rng.uniform(0.02, 0.08)),
                fin_rays=float(rng.uniform(15, 45)), ray_contrast=float(rng.uniform(0.0, 0.15)))


def _skin(rng: np.random.Generator, sp: Species, mesh: FishMesh) -> np.ndarray:
    """(N, 3) BGR albedo: countershading, scale mottle and the species' markings."""
    back, belly = np.asarray(sp.back), np.asarray(sp.belly)
    tone = rng.uniform(0.8, 1.15)
    b = np.clip((mesh.belly - 0.25) / 0.6, 0, 1)
    b = b * b * (3 - 2 * b)
    alb = back[None] * (1 - b[:, None]) + belly[None] * b[:, None]
    alb *= tone * (1.0 + rng.normal(0, 0.06, len(alb)))[:, None]           # scale mottle
    x, z = mesh.verts[:, 0] / mesh.length_mm, mesh.verts[:, 2] / mesh.length_mm
    u = mesh.along
    if sp.markings == "bars":
        alb *= (1 - 0.25 * (np.cos(2 * np.pi * u * 4.5) > 0.3) * (u > 0.2))[:, None]
    elif sp.markings == "spots":
        alb *= (1 - 0.45 * ((rng.random(len(alb)) < 0.12) & (mesh.belly < 0.45)))[:, None]
    elif sp.markings == "band":
        band = np.exp(-((mesh.belly - 0.5) / 0.08) ** 2)
        alb = alb * (1 - 0.35 * band[:, None]) + 0.35 * band[:, None] * np.array([0.55, 0.5, 0.85])
        alb *= (1 - 0.4 * ((rng.random(len(alb)) < 0.15) & (mesh.belly < 0.5)))[:, None]
    elif sp.markings == "gill_spot":
        spot = np.exp(-(((x - 0.26) / 0.03) ** 2 + ((z - 0.07) / 0.03) ** 2))
        alb *= (1 - 0.5 * spot)[:, None]
    return np.clip(alb, 0.02, 1.0)


_ALONG = np.linspace(0, 1, 12)[:, None]


def segment_distance(a0, a1, b0, b1) -> float:
    """Shortest distance between 3-D segments a0-a1 and b0-b1 (sampled: fish bodies, not CAD)."""
    return float(segment_distances(a0, a1, np.asarray(b0)[None], np.asarray(b1)[None])[0])


def segment_distances(a0, a1, b0s: np.ndarray, b1s: np.ndarray) -> np.ndarray:
    """(K,) ``segment_distance`` from a0-a1 to each of the K segments b0s[k]-b1s[k] (K, 3)."""
    pa = a0 + (a1 - a0) * _ALONG
    pb = b0s[:, None] + (b1s - b0s)[:, None] * _ALONG[None]
    return np.linalg.norm(pa[None, :, None] - pb[:, None, :], axis=-1).min(axis=(1, 2))


def clear_of(fish: Fish, others: list[Fish]) -> bool:
    """No body intersects another (painter's order is then right for whole fish)."""
    if not others:
        return True
    s, f, r = fish.segment_radius()
    snouts, forks, radii = zip(*(o.segment_radius() for o in others), strict=True)
    gaps = segment_distances(s, f, np.asarray(snouts), np.asarray(forks))
    return not bool(np.any(gaps < 0.9 * (r + np.asarray(radii))))
