"""The pond as the cleaner sees it: the outline, the keep-outs, and the floor it can reach.

Definitions (pond frame, metres):
- ``free(r)``: where the robot's CENTRE may be with a body of radius r: the outline eroded by r,
  minus every keep-out grown by r. A robot whose centre stays in it never touches the pond edge
  nor a keep-out. Where that space falls apart in pieces (a keep-out too close to a wall), only
  the largest piece counts: the robot cannot cross to the others.
- ``reachable(r, b)``: the floor a brush b wide centred under the robot can clean: ``free(r)``
  grown by b/2 (the brush turning on the spot sweeps a disc of radius b/2), clipped to the pond
  minus the keep-outs. With b <= 2r it is the pond floor less a band along the walls and round
  the keep-outs that no robot of that body can brush. Coverage figures are fractions of it.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.validation import explain_validity

from controller.errors import BadInput

ROUND = 8          # segments per quarter circle when growing shapes: fine enough at pond scale
# GEOS draws a round join of angle A as round(A / q) chords (q = a quarter circle / ROUND): one
# chord can span up to 1.5 q (a 24-sided keep-out's 15 degree corners get one 15 degree chord),
# and a chord's middle lies cos(half its span) inside the true arc. Growing by r / CHORD puts
# every chord on or outside the arc of radius r.
CHORD = math.cos(0.75 * (math.pi / 2) / ROUND)


def _ring(points, where: str, key: str) -> Polygon:
    try:
        xy = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise BadInput(where, key, "must be a list of [x, y] points in metres") from None
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise BadInput(where, key, "must be a list of [x, y] points in metres")
    if not np.isfinite(xy).all():
        raise BadInput(where, key, "every coordinate must be a finite number")
    if len(xy) > 1 and np.array_equal(xy[0], xy[-1]):
        xy = xy[:-1]                              # a closed ring repeats its first point: accepted
    if len(np.unique(xy, axis=0)) < 3:
        raise BadInput(where, key, f"needs at least 3 distinct points, has {len(np.unique(xy, axis=0))}")
    centred = xy - xy.mean(axis=0)
    if np.linalg.matrix_rank(centred, tol=1e-9 * max(1.0, float(np.abs(centred).max()))) < 2:
        raise BadInput(where, key, "has zero area (its points lie on one line)")
    poly = Polygon(xy)
    if not poly.exterior.is_simple:
        raise BadInput(where, key, "crosses itself (self-intersecting outline)")
    if not poly.is_valid or poly.area < 1e-9:
        raise BadInput(where, key, f"is not a simple polygon: {explain_validity(poly).lower()}")
    return shapely.normalize(poly)


def _largest(geom) -> Polygon:
    if isinstance(geom, Polygon):
        return geom
    if isinstance(geom, MultiPolygon) and not geom.is_empty:
        return max(geom.geoms, key=lambda g: g.area)
    return Polygon()


@dataclass(frozen=True)
class PondGeometry:
    outline: Polygon
    keepouts: tuple[Polygon, ...]

    def free(self, body_radius_m: float) -> Polygon:
        """Where the robot's centre may be (largest connected piece; empty if it fits nowhere)."""
        return _free(self, float(body_radius_m))

    def reachable(self, body_radius_m: float, brush_m: float) -> Polygon:
        """The floor the brush can reach (module docstring); may be empty."""
        return _reachable(self, float(body_radius_m), float(brush_m))

    @property
    def water(self) -> Polygon:
        """The pond floor less the keep-outs."""
        return self.outline.difference(shapely.union_all(self.keepouts)) if self.keepouts else self.outline


@lru_cache(maxsize=32)
def _free(geom: PondGeometry, r: float) -> Polygon:
    # the chords lie on or outside the true arcs (CHORD), so the free space never lets the body touch
    space = geom.outline.buffer(-r / CHORD, quad_segs=ROUND)
    if geom.keepouts:
        space = space.difference(grown(geom.keepouts, r))
    return _largest(space.buffer(0))


def grown(shapes, r: float):
    """The union of ``shapes`` grown by at least ``r`` everywhere (their Minkowski sum with a disc
    of radius r, drawn with chords that never cut inside it)."""
    return shapely.union_all([s.buffer(r / CHORD, quad_segs=ROUND) for s in shapes])


@lru_cache(maxsize=32)
def _reachable(geom: PondGeometry, r: float, b: float) -> Polygon:
    free = _free(geom, r)
    if free.is_empty:
        return free
    return _largest(free.buffer(b / 2, quad_segs=ROUND).intersection(geom.water))


def pond_geometry(outline_xy, keepouts_xy: Sequence = (), *, where: str = "config",
                  key: str = "cleaning.outline", keepouts_key: str = "cleaning.keepouts") -> PondGeometry:
    """Validate the pond and its keep-outs; every fault is a ``BadInput`` naming the key."""
    outline = _ring(outline_xy, where, key)
    keepouts: list[Polygon] = []
    for i, points in enumerate(keepouts_xy):
        k_key = f"{keepouts_key}[{i}]"
        k = _ring(points, where, k_key)
        if not k.intersects(outline) or k.touches(outline):
            raise BadInput(where, k_key, "lies outside the pond")
        if not outline.covers(k):
            raise BadInput(where, k_key, "crosses the pond's edge")
        for j, other in enumerate(keepouts):
            if k.relate_pattern(other, "T********"):
                raise BadInput(where, k_key, f"overlaps {keepouts_key}[{j}]")
        keepouts.append(k)
    return PondGeometry(outline, tuple(keepouts))


def disc(x_m: float, y_m: float, radius_m: float, points: int = 32) -> list[tuple[float, float]]:
    """A round keep-out (a feeder's foot, a drain) as the polygon config takes."""
    a = np.linspace(0.0, 2 * math.pi, points, endpoint=False)
    return [(x_m + radius_m * math.cos(t), y_m + radius_m * math.sin(t)) for t in a]
