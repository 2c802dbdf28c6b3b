"""Boustrophedon coverage plan over a pond outline with keep-outs (any simple polygon with holes).

The robot's centre moves in ``free`` (geometry.py); lanes and edge passes keep a margin beyond it
round the keep-outs (``keepout_margin_m``: no wall stops the robot there). The plan is made of:
- lanes: that space sliced by parallel lines at the lane spacing (brush width less the overlap),
  the slices grouped into cells (consecutive slices overlapping one to one: a boustrophedon
  decomposition), each cell mown back and forth;
- edge passes: one round the pond's wall and one round each keep-out (EDGE inside the space). They
  brush the bands that lanes ending at a slanted or curved edge leave in saw teeth.
Cells and edge passes are ordered, with the way through each, for the least straight-line travel
between them (Held-Karp up to EXACT_TASKS, nearest-first beyond); every move runs straight where
the space allows, else along the shortest way round the keep-outs (a visibility graph; through
the body-clear free space where the margin closes a gap, keeping ``TRANSIT_MARGIN`` even there; what
lies beyond a gap narrower than that is not planned: the geofence would refuse the way).
The sweep angle, unless given, is the one of a few candidates (the axes and the pond's longest
edges) giving the least length plus TURN_M per turn. The path is resampled every ``step_m`` so
the follower's progress index (steering.py) is fine enough to resume from.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
import shapely.ops
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from shapely import affinity
from shapely.geometry import LineString, Polygon

from controller.cleaning.geometry import PondGeometry, grown
from controller.errors import BadInput

EDGE = 0.005         # m: the edge pass runs this far inside the free space (the walls hold the robot)
LANE_INSET = 0.25    # of the brush width: lanes stop this far short of the free space's edge
TURN_M = 2.0         # a turn costs as much as this much path when choosing the sweep angle
NODE_IN = 0.03       # m: the route graph's corners lie this far inside the space
EXACT_TASKS = 9      # cells and edge passes ordered exactly up to this many (Held-Karp), nearest-first beyond
RING_WAYS_IN = 8     # places considered for starting an edge pass
SLIVER = 0.05        # m: lane pieces shorter than this are left to the edge pass
KEEPOUT_MARGIN = 0.10  # m: beyond the body radius, round keep-outs (no wall stops the robot there)
TRANSIT_MARGIN = 0.07  # m: the least kept on the moves between pieces the margin cuts apart: the geofence
                       # refuses a body within 0.03 + 0.02 slack + 2 x a tracked pose's std (~0.01) of a
                       # keep-out (a move through free space passed 0.016 m from one, into a refusal)


@dataclass(frozen=True)
class CoveragePlan:
    path: np.ndarray          # (N, 2) waypoints, pond metres, in the order to drive them
    lanes: int
    length_m: float
    angle_rad: float = 0.0    # the lanes' direction
    turns: int = 0            # corners sharper than 45 degrees


class _Graph:
    """Shortest ways between two points inside a polygon with holes (a visibility graph)."""

    def __init__(self, space, inset: float = NODE_IN):
        self.ok = space.buffer(1e-6)
        shapely.prepare(self.ok)
        # corners set in far enough that the chord between two neighbours round a curved keep-out
        # stays inside the space (else the graph breaks round it and ways detour absurdly); with
        # no inset, the space's own corners: the ways through a neck narrower than two insets
        inner = space.buffer(-inset, join_style="mitre").simplify(inset / 5) if inset > 0 else space
        rings = [r for p in _pieces(inner) for r in (p.exterior, *p.interiors)]
        self.nodes = np.array([xy for r in rings for xy in r.coords[:-1]]) if rings else np.zeros((0, 2))
        n = len(self.nodes)
        i, j = np.triu_indices(n, 1)
        seen = self.clear(self.nodes[i], self.nodes[j])
        w = np.hypot(*(self.nodes[i[seen]] - self.nodes[j[seen]]).T)
        self.graph = csr_matrix((np.r_[w, w], (np.r_[i[seen], j[seen]], np.r_[j[seen], i[seen]])), shape=(n + 2, n + 2))

    def clear(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if len(a) == 0:
            return np.zeros(0, bool)
        return shapely.covers(self.ok, shapely.linestrings(np.stack([a, b], axis=1)))

    def way(self, a: np.ndarray, b: np.ndarray) -> list[np.ndarray] | None:
        if self.clear(a[None], b[None])[0]:
            return [a, b]
        n = len(self.nodes)
        va = self.clear(np.repeat([a], n, 0), self.nodes)
        vb = self.clear(np.repeat([b], n, 0), self.nodes)
        w = np.r_[np.hypot(*(self.nodes[va] - a).T), np.hypot(*(self.nodes[vb] - b).T)]
        ends = csr_matrix((w, (np.r_[np.full(va.sum(), n), np.flatnonzero(vb)],
                               np.r_[np.flatnonzero(va), np.full(vb.sum(), n + 1)])), shape=(n + 2, n + 2))
        dist, pred = dijkstra(self.graph + ends, indices=n, return_predecessors=True)
        if not np.isfinite(dist[n + 1]):
            return None
        chain = [int(pred[n + 1])]
        while pred[chain[-1]] != n:
            chain.append(int(pred[chain[-1]]))
        return [a, *self.nodes[chain[::-1]], b]


class Router:
    """Moves between two points: inside ``drive`` (the margin kept round the keep-outs) where it
    can, else inside ``free`` (the body clear by at least ``TRANSIT_MARGIN`` round the keep-outs)."""

    def __init__(self, free: Polygon, drive=None):
        self.spaces = [(drive, NODE_IN)] if drive is not None and drive is not free else []
        self.spaces += [(free, NODE_IN), (free, 0.0)]
        self.graphs: dict[int, _Graph] = {}          # built when first needed: the last rarely is

    def route(self, a, b) -> list[np.ndarray]:
        a, b = np.asarray(a, float), np.asarray(b, float)
        for i, (space, inset) in enumerate(self.spaces):
            if i not in self.graphs:
                self.graphs[i] = _Graph(space, inset)
            way = self.graphs[i].way(a, b)
            if way is not None:
                return way
        return [a, b]                     # no way round: the caller's containment check will say so


def _check(brush_m: float, body_radius_m: float, overlap: float, where: str, key: str) -> None:
    for name, v, ok in (("brush_m", brush_m, brush_m > 0), ("body_radius_m", body_radius_m, body_radius_m > 0),
                        ("overlap", overlap, 0 <= overlap < 0.5)):
        if not (math.isfinite(v) and ok):
            raise BadInput(where, f"{key}.{name}", f"out of range: {v}")


def _slices(free: Polygon, angle: float, brush: float, spacing: float) -> list[list[tuple[float, float, float]]]:
    """Cells of lanes, each lane (y, x0, x1) in the frame rotated by -angle."""
    rot = affinity.rotate(free, -angle, origin=(0, 0), use_radians=True)
    region = rot.buffer(-LANE_INSET * brush)
    minx, miny, maxx, maxy = rot.bounds
    lo, hi = miny + EDGE + spacing, maxy - EDGE - spacing       # the outer lanes abut the edge pass
    ys = [(miny + maxy) / 2] if hi <= lo else np.linspace(lo, hi, math.ceil((hi - lo) / spacing) + 1)
    cells: list[list[tuple[float, float, float]]] = []
    open_: list[tuple[int, tuple[float, float]]] = []
    for y in ys:
        cut = region.intersection(LineString([(minx - 1, y), (maxx + 1, y)]))
        parts = getattr(cut, "geoms", [cut])
        segs = sorted((min(c[0][0], c[-1][0]), max(c[0][0], c[-1][0]))
                      for c in (list(p.coords) for p in parts if p.geom_type == "LineString" and not p.is_empty)
                      if abs(c[-1][0] - c[0][0]) > SLIVER)
        now = []
        for s in segs:
            up = [(ci, o) for ci, o in open_ if o[0] < s[1] and s[0] < o[1]]
            if len(up) == 1 and sum(up[0][1][0] < t[1] and t[0] < up[0][1][1] for t in segs) == 1:
                ci = up[0][0]
            else:
                cells.append([])
                ci = len(cells) - 1
            cells[ci].append((float(y), *s))
            now.append((ci, s))
        open_ = now
    return cells


def _to_world(angle: float, x: float, y: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * x - s * y, s * x + c * y])


def _densify(points: list[np.ndarray], step: float) -> np.ndarray:
    out = [points[0]]
    for a, b in zip(points, points[1:], strict=False):
        n = max(1, math.ceil(np.hypot(*(b - a)) / step))
        out.extend(a + (b - a) * k / n for k in range(1, n + 1))
    return np.array(out)


def _loop(ring, step: float) -> np.ndarray:
    pts = np.asarray(ring.coords)
    return _densify(list(pts), step)[:-1]


class _Builder:
    def __init__(self, router: Router, start: np.ndarray):
        self.router, self.points, self.lanes = router, [start], 0

    def go(self, p: np.ndarray) -> None:
        self.points.extend(self.router.route(self.points[-1], p)[1:])

    def ring(self, loop: np.ndarray, k: int) -> None:
        for p in (*loop[k:], *loop[:k + 1]):
            self.go(p)

    def cell(self, lanes: list[tuple[np.ndarray, np.ndarray]]) -> None:
        for a, b in lanes:
            self.go(a)
            self.points.append(b)
            self.lanes += 1


def _cell_variants(angle: float, cell) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    out = []
    for order in (cell, cell[::-1]):
        for flip in (0, 1):
            ends = [((x1, x0) if (i + flip) % 2 else (x0, x1), y) for i, (y, x0, x1) in enumerate(order)]
            out.append([(_to_world(angle, a, y), _to_world(angle, b, y)) for (a, b), y in ends])
    return out


def _pieces(geom) -> list[Polygon]:
    return [g for g in getattr(geom, "geoms", [geom]) if isinstance(g, Polygon) and g.area > 1e-4]


def _order(ends: list[list[tuple[np.ndarray, np.ndarray]]], start: np.ndarray) -> list[tuple[int, int]]:
    """The order of the tasks, and the way through each (its (entry, exit) variants), with the
    least straight-line distance between them: Held-Karp over up to EXACT_TASKS tasks,
    nearest-first beyond."""
    n = len(ends)
    if n == 0:
        return []
    V = max(len(e) for e in ends)
    entry, exit_ = np.full((n, V, 2), np.nan), np.full((n, V, 2), np.nan)
    for t, e in enumerate(ends):
        entry[t, :len(e)] = [a for a, _ in e]
        exit_[t, :len(e)] = [b for _, b in e]
    gap = np.hypot(*(exit_[:, :, None, None, :] - entry[None, None]).transpose(4, 0, 1, 2, 3))   # (n,V,n,V)
    first = np.hypot(*(entry - start).transpose(2, 0, 1))                  # (n, V)
    gap, first = np.nan_to_num(gap, nan=np.inf), np.nan_to_num(first, nan=np.inf)
    if n > EXACT_TASKS:
        order, here, left = [], None, set(range(n))
        while left:
            cost = first if here is None else gap[here]
            ci, vi = min(((c, v) for c in left for v in range(V)), key=lambda cv: cost[cv])
            order.append((ci, vi))
            here = (ci, vi)
            left.remove(ci)
        return order
    full = (1 << n) - 1
    best = np.full((1 << n, n, V), np.inf)
    back = np.full((1 << n, n, V, 2), -1, dtype=int)
    for c in range(n):
        best[1 << c, c] = first[c]
    for mask in range(1, full + 1):
        done = [c for c in range(n) if mask >> c & 1]
        if len(done) < 1:
            continue
        here = best[mask][done].reshape(-1)                                # (k*V,)
        if not np.isfinite(here).any():
            continue
        for c in range(n):
            if mask >> c & 1:
                continue
            via = here[:, None] + gap[done][:, :, c, :].reshape(-1, V)       # (k*V, V)
            k = np.argmin(via, axis=0)
            cost = via[k, np.arange(V)]
            nxt = mask | 1 << c
            better = cost < best[nxt, c]
            best[nxt, c][better] = cost[better]
            back[nxt, c][better] = np.stack([np.array(done)[k // V], k % V], axis=1)[better]
    c, v = np.unravel_index(np.argmin(best[full]), (n, V))
    order, mask = [], full
    while c >= 0:
        order.append((int(c), int(v)))
        pc, pv = back[mask, c, v]
        mask &= ~(1 << int(c))
        c, v = pc, pv
    return order[::-1]


def _plan_at(drive, router: Router, angle: float, start: np.ndarray, brush: float,
             spacing: float, step: float) -> CoveragePlan:
    pieces = _pieces(drive.buffer(-EDGE, join_style="mitre"))
    loops = [_loop(r, step) for g in pieces for r in (g.exterior, *g.interiors)]
    build = _Builder(router, start)
    cells = [_cell_variants(angle, c) for c in _slices(drive, angle, brush, spacing)]
    ways = [np.linspace(0, len(h), RING_WAYS_IN, endpoint=False).astype(int) for h in loops]
    ends = [[(v[0][0], v[-1][1]) for v in c] for c in cells]
    ends += [[(h[k], h[k]) for k in w] for h, w in zip(loops, ways, strict=True)]
    for t, v in _order(ends, start):
        if t < len(cells):
            build.cell(cells[t][v])
        else:
            build.ring(loops[t - len(cells)], int(ways[t - len(cells)][v]))
    pts = [p for i, p in enumerate(build.points) if i == 0 or np.hypot(*(p - build.points[i - 1])) > 1e-9]
    legs = np.diff(np.array(pts), axis=0)
    heading = np.arctan2(legs[:, 1], legs[:, 0])
    turns = int(np.sum(np.abs(np.angle(np.exp(1j * np.diff(heading)))) > math.pi / 4))
    path = _densify(pts, step)
    length = float(np.sum(np.hypot(*np.diff(path, axis=0).T)))
    return CoveragePlan(path, build.lanes, length, float(angle), turns)


def _candidate_angles(outline: Polygon) -> list[float]:
    xy = np.asarray(outline.exterior.coords)
    d = np.diff(xy, axis=0)
    longest = np.argsort(-np.hypot(*d.T))[:4]
    angles: list[float] = []
    for a in (0.0, math.pi / 2, *(math.atan2(d[i, 1], d[i, 0]) % math.pi for i in longest)):
        if all(abs(math.remainder(a - b, math.pi)) > math.radians(1) for b in angles):
            angles.append(float(a))
    return angles


def drivable(geom: PondGeometry, free: Polygon, body_radius_m: float, margin: float):
    """Where lanes and edge passes run: the free space less a margin round the keep-outs. Where
    that margin cuts it in pieces, every piece is mown; moves between them go through ``free``."""
    if margin <= 0 or not geom.keepouts:
        return free
    return free.difference(grown(geom.keepouts, body_radius_m + margin))


def _reached(drive, transit, start: np.ndarray):
    """(the pieces of ``drive``, the piece of ``transit``) the robot gets to from ``start`` without
    passing closer to a keep-out than ``transit`` allows: a gap narrower than that is no way through
    (the geofence would refuse the move), and what lies only beyond it is not planned."""
    pieces = _pieces(transit)
    if len(pieces) <= 1:
        return drive, transit
    home = min(pieces, key=lambda p: p.distance(shapely.Point(start)))
    kept = [p for p in _pieces(drive) if home.intersection(p).area > 0.5 * p.area]
    return (shapely.union_all(kept) if kept else drive), home


def _start(start_xy, geom: PondGeometry, transit) -> np.ndarray:
    """Where the path starts: the dock, or, where the dock lies within the keep-outs' transit margin
    (on the floor, yet closer to one than a move may pass), the nearest point clear of it -- every
    way out of the dock was no way, and the first move ran straight through the keep-out. Without a
    dock, the point of the largest piece of the floor nearest the outline's first corner (a corner
    in a pocket behind a keep-out planned the pocket alone: a 0.4 m path)."""
    pieces = _pieces(transit.buffer(-EDGE))
    if not pieces:                                 # (no room clear of the margin: the free space's edge)
        pieces = _pieces(transit)
    if start_xy is None:
        pieces = [max(pieces, key=lambda g: g.area)]
    at = shapely.Point(geom.outline.exterior.coords[0] if start_xy is None else start_xy)
    inside = shapely.union_all(pieces)
    if inside.covers(at):
        return np.asarray(at.coords[0], float)
    return np.asarray(shapely.ops.nearest_points(inside, at)[0].coords[0], float)


def plan_coverage(geom: PondGeometry, *, brush_m: float, body_radius_m: float, overlap: float = 0.05,
                  angle_rad: float | None = None, start_xy=None, step_m: float = 0.25,
                  keepout_margin_m: float = KEEPOUT_MARGIN,
                  where: str = "config", key: str = "cleaning") -> CoveragePlan:
    """The path covering the reachable floor (module docstring). ``start_xy``: where the robot
    starts (the dock); by default a point of the largest piece of floor (``_start``).
    ``keepout_margin_m``: room left for steering error round the keep-outs, beyond the body radius
    (the walls need none: they stop the robot; a keep-out does not). BadInput if no plan keeps the
    body out of the keep-outs (a move with no way round them is never handed on)."""
    _check(brush_m, body_radius_m, overlap, where, key)
    free = geom.free(body_radius_m)
    drive = drivable(geom, free, body_radius_m, keepout_margin_m)
    if free.is_empty or drive.area < 1e-4:
        raise BadInput(where, f"{key}.outline", f"no room for a robot of radius {body_radius_m} m")
    transit = drivable(geom, free, body_radius_m, min(TRANSIT_MARGIN, keepout_margin_m))
    start = _start(start_xy, geom, transit)
    drive, transit = _reached(drive, transit, start)
    router = Router(transit, drive)
    spacing = brush_m * (1 - overlap)
    angles = [float(angle_rad)] if angle_rad is not None else _candidate_angles(geom.outline)
    plans = [_plan_at(drive, router, a, start, brush_m, spacing, step_m) for a in angles]
    best = min(plans, key=lambda p: p.length_m + TURN_M * p.turns)
    if geom.keepouts and len(best.path) > 1:
        body = LineString(best.path).buffer(body_radius_m - 1e-6)
        if shapely.union_all(geom.keepouts).intersection(body).area > 1e-9:
            raise BadInput(where, f"{key}.dock", "no way from the dock to the floor that keeps the robot out of "
                                                 "the keep-outs")
    return best
