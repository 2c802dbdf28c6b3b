"""The mop-up: after the boustrophedon path, short passes over the reachable floor the coverage
map still calls dirty, within a cap, and then home.

Why: the lanes leave gaps where the robot crabbed off its lane, and the follower gives up
waypoints the geofence keeps refusing (steering.py); the plan never comes back to them.

- ``plan_mopup``: the map's dirty reachable cells, less those given up, in patches (8-connected,
  gaps of one cell closed). For each patch, the space where the robot's centre may be (the
  plan's drive space: coverage.drivable) and brushes it (the patch grown by half the brush) is
  cut by lines along the patch's long axis, at most ``spacing`` apart across it: the passes. A
  cell no centre in that space brushes (a sliver next to a keep-out inside the plan's margin, or
  along a wall) is out of reach and left alone, and so are patches of fewer than MIN_CELLS cells:
  on the demo pond most of those are the map's noise, clean on the true poses (bench_cleaning_loop).
  The passes are taken greedily from where the robot is, the one giving the most
  dirty cells per metre of way to it and along it next, as long as the whole stays within
  ``max_m``, each bringing at least MIN_YIELD cells a metre: every metre over clean floor counts
  as overlap, so the cap is the overlap spent.
- ``MopUp`` drives that plan with the cleaner's follower (and geofence); its account lives in
  the map (``CoverageMap.mopup``, ``given_up``), which the ledger keeps: a restarted controller
  plans again from the saved map with what is left of the cap. A pass the follower has gone past
  with cells it aimed at still dirty (the fence refused it again) gives them up for good, logged
  once. The cap is ``max_m`` of the plans' path gone by (the follower's progress: the metres a
  noisy pose sweeps would overstate it) and ``max_s`` farm seconds, over restarts: a plan is made
  within what is left of the metres, and the mop-up ends when it is driven or the seconds are
  spent (a patch the robot cannot get to does not keep it out all night).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString

from controller.cleaning.coverage import SLIVER, _densify

log = logging.getLogger("fishfarm.cleaner")

MIN_CELLS = 3        # a smaller patch is mostly the map's noise (the tracked pose's 3 cm): not worth the way
MIN_YIELD = 3.0      # dirty cells per metre (way there and pass): below it, a pass buys less floor than
                     # the overlap it costs (one metre over clean floor is 1/400 of the demo's path)
REACH_TOL = 0.02     # m: a cell counts as brushed by a pass when its centre is this far inside the brush
EXTRA_MARGIN_M = 0.10   # m round keep-outs beyond the plan's margin (``spaces``)
STALL_S = 30.0       # farm s without a waypoint reached: the pass is given up
TILE_M = 1.5        # a patch is cut in squares this size, each mopped along its own long axis


@dataclass(frozen=True)
class Pass:
    a: np.ndarray              # one end (the robot's centre), pond metres
    b: np.ndarray              # the other
    cells: np.ndarray          # flat indices of the map's dirty cells it brushes


@dataclass(frozen=True)
class MopupPlan:
    path: np.ndarray           # (N, 2) from the robot's position
    passes: tuple[Pass, ...]   # in the order driven (each a -> b)
    ends: tuple[int, ...]      # per pass, the path index of its end
    length_m: float
    aimed: int                 # dirty cells the passes brush
    out_of_reach: int          # dirty cells no pass can brush


def dirty(cmap) -> np.ndarray:
    """Reachable cells not cleaned and not given up."""
    return cmap.reachable & ~cmap.cleaned() & ~cmap.given_up


def _centres(cmap, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    return np.c_[cmap.origin[0] + (cols + 0.5) * cmap.cell_m, cmap.origin[1] + (rows + 0.5) * cmap.cell_m]


def _patches(mask: np.ndarray) -> list[np.ndarray]:
    """Flat indices of the dirty cells of each patch (cells a cell apart belong together)."""
    closed = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    n, labels = cv2.connectedComponents(closed | mask.astype(np.uint8), connectivity=8)
    flat = np.flatnonzero(mask)
    owner = labels.reshape(-1)[flat]
    order = np.argsort(owner, kind="stable")
    cuts = np.flatnonzero(np.diff(owner[order])) + 1
    return [g for g in np.split(flat[order], cuts) if len(g)]


def _axis(xy: np.ndarray) -> float:
    """The long axis of cell centres: their principal direction (0 for one cell)."""
    if len(xy) < 2:
        return 0.0
    _, v = np.linalg.eigh(np.cov((xy - xy.mean(axis=0)).T))
    return math.atan2(v[1, -1], v[0, -1])


def _tiles(cmap, cells: np.ndarray) -> list[np.ndarray]:
    """A patch cut in TILE_M squares: a patch bent round a keep-out has no one long axis, its
    pieces have. One a lane covers across its long axis stays whole (cut, it would take two
    passes' run-ins)."""
    rows, cols = np.unravel_index(cells, cmap.first_m.shape)
    angle = _axis(_centres(cmap, rows, cols))
    across = _centres(cmap, rows, cols) @ [-math.sin(angle), math.cos(angle)]
    if np.ptp(across) <= cmap.brush_m / 2:
        return [cells]
    n = max(1, round(TILE_M / cmap.cell_m))
    tile = (rows // n) * (cmap.first_m.shape[1] // n + 1) + cols // n
    order = np.argsort(tile, kind="stable")
    return np.split(cells[order], np.flatnonzero(np.diff(tile[order])) + 1)


def _room_axis(room, cells_axis: float) -> float:
    """The direction passes run in: the long side of the room for the robot's centre when that room
    is long and thin (by a wall, the room is a few centimetres wide, and lines along the cells' own
    axis, a cell's tilt off the wall, only cut its corners: an outside tester's 1 m strip by a wall
    stayed dirty, "out of reach"); else the cells' own long axis."""
    rect = room.minimum_rotated_rectangle
    if rect.geom_type != "Polygon":
        return cells_axis
    a, b, c = np.asarray(rect.exterior.coords)[:3]
    sides = sorted((b - a, c - b), key=lambda v: float(np.hypot(*v)))
    if np.hypot(*sides[1]) < 2 * np.hypot(*sides[0]):
        return cells_axis
    return math.atan2(sides[1][1], sides[1][0])


def _patch_passes(cmap, cells: np.ndarray, drive, brush: float, spacing: float) -> list[Pass]:
    """The passes over one patch (module docstring)."""
    rows, cols = np.unravel_index(cells, cmap.first_m.shape)
    xy = _centres(cmap, rows, cols)
    half = brush / 2
    room = drive.intersection(shapely.union_all(shapely.buffer(shapely.points(xy), half - 1e-3)))
    if room.is_empty:
        return []
    angle = _room_axis(room, _axis(xy))
    c, s = math.cos(angle), math.sin(angle)
    along, across = xy @ [c, s], xy @ [-s, c]
    rot = affinity.rotate(room, -angle, origin=(0, 0), use_radians=True)
    lo, hi = rot.bounds[1] + 1e-3, rot.bounds[3] - 1e-3
    n = max(1, math.ceil((across.max() - across.min() + cmap.cell_m) / spacing))
    wanted = np.linspace(across.min(), across.max(), n + 2)[1:-1] if n > 1 else [across.mean()]
    out = []
    # besides the lanes across it, lines through the room half a lane apart: where the room bends
    # (round a keep-out) the lane at the patch's own offset may miss it; the greedy choice drops
    # the ones that add nothing
    spare = np.arange(lo, hi, spacing / 2) if lo <= hi else np.array([(lo + hi) / 2])
    for off in np.unique(np.r_[np.clip(wanted, lo, hi), spare] if lo <= hi else spare):
        line = LineString([(along.min() - 2 * brush, off), (along.max() + 2 * brush, off)])
        cut = rot.intersection(line)
        for piece in getattr(cut, "geoms", [cut]):
            if piece.geom_type != "LineString" or piece.length < SLIVER:
                continue
            (x0, _), (x1, _) = piece.coords[0], piece.coords[-1]
            x0, x1 = min(x0, x1), max(x0, x1)
            hit = (np.abs(across - off) <= half - REACH_TOL) & (along >= x0) & (along <= x1)
            if hit.any():
                ends = [np.array([c * x - s * off, s * x + c * off]) for x in (x0, x1)]
                out.append(Pass(ends[0], ends[1], cells[hit]))
    return out


def plan_mopup(cmap, drive, router, start, *, brush_m: float, spacing_m: float, max_m: float,
               step_m: float = 0.25, min_yield: float = MIN_YIELD) -> MopupPlan:
    """The mop-up from ``start`` (module docstring); ``router.route(a, b)`` the way between passes."""
    start = np.asarray(start, float)
    mask = dirty(cmap)
    rows, cols = np.nonzero(mask)
    xy = _centres(cmap, rows, cols)
    brushed = drive.buffer(brush_m / 2 - REACH_TOL)        # a centre in drive brushes these
    inside = np.zeros_like(mask)
    inside[rows, cols] = shapely.contains_xy(brushed, xy[:, 0], xy[:, 1])
    patches = [c for c in _patches(inside) if len(c) >= MIN_CELLS]
    passes = [p for cells in patches for piece in _tiles(cmap, cells)
              for p in _patch_passes(cmap, piece, drive, brush_m, spacing_m)]
    reach = np.zeros(mask.size, bool)
    for p in passes:
        reach[p.cells] = True
    chosen, ways, done = [], [], np.zeros(mask.size, bool)
    spent, here = 0.0, start
    while passes:
        gains = np.array([np.count_nonzero(~done[p.cells]) for p in passes])
        ends = np.array([[p.a, p.b] for p in passes])                     # (P, 2 ways in, 2)
        total = np.hypot(*(ends - here).transpose(2, 0, 1)) + np.hypot(*(ends[:, 1] - ends[:, 0]).T)[:, None]
        fits = (spent + total <= max_m) & (gains[:, None] > 0) & (gains[:, None] >= min_yield * total)
        if not fits.any():
            break
        score = np.where(fits, gains[:, None] / np.maximum(total, 1e-3), -1.0)
        i, flip = np.unravel_index(int(np.argmax(score)), score.shape)
        p = passes.pop(int(i))
        a, b = (p.b, p.a) if flip else (p.a, p.b)
        way = [np.asarray(q, float) for q in router.route(here, a)] + [b]
        leg = sum(math.dist(u, v) for u, v in zip(way, way[1:], strict=False))
        if spent + leg > max_m:          # the way round a keep-out is longer than the straight line
            continue
        spent, here = spent + leg, b
        chosen.append(Pass(a, b, p.cells))
        ways.append(way)
        done[p.cells] = True
    dense, end_idx = [start], []
    for way in ways:                     # resampled every step_m; each pass's end keeps its index
        for q in way[1:]:
            if math.dist(q, dense[-1]) > 1e-9:
                dense.extend(_densify([dense[-1], q], step_m)[1:])
        end_idx.append(len(dense) - 1)
    return MopupPlan(np.array(dense), tuple(chosen), tuple(end_idx), spent, int(done.sum()),
                     int(np.count_nonzero(mask.reshape(-1) & ~reach)))


class MopUp:
    """Drives a mop-up plan (module docstring). ``command`` gives thrust, or None once it is over."""

    def __init__(self, cmap, plan: MopupPlan, follower, *, max_m: float, max_s: float):
        self.map, self.plan, self.follower = cmap, plan, follower
        self.max_m, self.max_s = max_m, max_s
        self._judged = 0                 # passes judged so far
        self._at, self._still_s = follower.progress, 0.0     # the waypoint, and how long it has held
        if cmap.mopup is None:
            cmap.mopup = {"m": 0.0, "s": 0.0, "done": False}
        self._before_m = cmap.mopup["m"]     # gone by on earlier plans (before a restart)
        if cmap.mopup["done"]:
            return
        if not plan.passes:
            cmap.mopup["done"] = True
        log.info("cleaner: mop-up of %d passes, %.1f m, over %d dirty cells (%d out of its reach: specks of "
                 "under %d cells, floor by keep-outs within its margin or in corners)",
                 len(plan.passes), plan.length_m, plan.aimed, plan.out_of_reach, MIN_CELLS)

    @property
    def done(self) -> bool:
        return bool(self.map.mopup["done"])

    def spent(self) -> tuple[float, float]:
        """Metres of planned path gone by and farm seconds run since the mop-up began (over restarts)."""
        return self.map.mopup["m"], self.map.mopup["s"]

    def command(self, x: float, y: float, heading: float, dt_s: float | None = None,
                refused: int = 0) -> tuple[float, float] | None:
        if self.done:
            return None
        self.map.mopup["s"] += dt_s or 0.0
        capped = self.map.mopup["s"] > self.max_s or self.map.mopup["m"] > self.max_m
        self._unstall(dt_s or 0.0)
        command = None if capped else self.follower.command(x, y, heading, dt_s=dt_s, refused=refused)
        self.map.mopup["m"] = self._before_m + float(self.follower.s[self.follower.progress])
        metres, seconds = self.spent()
        self._judge(len(self.plan.passes) if self.follower.done else self._passed())
        if capped or self.follower.done:
            self.map.mopup["done"] = True
            log.info("cleaner: mop-up over%s after %.1f m, %.0f s", " (its cap)" if capped else "", metres, seconds)
            return None
        return command

    def _unstall(self, dt: float) -> None:
        """No waypoint for STALL_S (the follower and the fence at a standoff by a keep-out, each
        command let through at a crawl): the rest of this pass, or of the way to the next, is
        given up (its cells then judged as any pass gone by)."""
        if self.follower.progress != self._at:
            self._at, self._still_s = self.follower.progress, 0.0
            return
        self._still_s += dt
        if self._still_s < STALL_S:
            return
        k = int(np.searchsorted(np.asarray(self.plan.ends), self.follower.progress, side="left"))
        after = self.plan.ends[k] + 1 if k < len(self.plan.ends) else len(self.follower.path)
        log.warning("cleaner: mop-up stalled %.0f s near (%.1f, %.1f): %s", self._still_s,
                    *self.follower.path[self.follower.progress],
                    "on to the next pass" if after < len(self.follower.path) else "over")
        if after < len(self.follower.path):
            self.follower.skip_to(after)
        else:
            self.follower.done = True
        self._at, self._still_s = self.follower.progress, 0.0

    def _passed(self) -> int:
        """Passes whose end the follower has gone beyond (the next one's begun)."""
        return int(np.searchsorted(np.asarray(self.plan.ends), self.follower.progress, side="left"))

    def _judge(self, upto: int) -> None:
        cleaned = self.map.cleaned().reshape(-1)
        for k in range(self._judged, upto):
            left = self.plan.passes[k].cells[~cleaned[self.plan.passes[k].cells]]
            if len(left):
                self.map.given_up.flat[left] = True
                xy = self.plan.passes[k].a
                log.warning("cleaner: mop-up gives up %d cells near (%.1f, %.1f): not brushed on its pass",
                            len(left), xy[0], xy[1])
        self._judged = max(self._judged, upto)


def spaces(geom, body_radius_m: float, keepout_margin_m: float):
    """The mop-up's drive space and router: the plan's space with EXTRA_MARGIN_M more round the
    keep-outs (its passes and the ways between them turn sharply there, as the plan's smooth
    edge pass round a keep-out does not)."""
    from controller.cleaning.coverage import Router, drivable
    free = geom.free(body_radius_m)
    drive = drivable(geom, free, body_radius_m, keepout_margin_m + EXTRA_MARGIN_M)
    return drive, Router(free, drive)


def begin(cmap, drive, router, start, follow, *, brush_m: float, spacing_m: float, max_m: float,
          max_s: float, min_yield: float = MIN_YIELD) -> MopUp:
    """The mop-up from ``start`` on this map: planned with what is left of the cap (none to plan
    once it is over); ``follow(path, 0)`` the cleaner's path follower."""
    over = cmap.mopup is not None and cmap.mopup["done"]
    metres = 0.0 if cmap.mopup is None else cmap.mopup["m"]
    left = 0.0 if over else max(0.0, max_m - metres)
    plan = plan_mopup(cmap, drive, router, start, brush_m=brush_m, spacing_m=spacing_m, max_m=left,
                      min_yield=min_yield)
    return MopUp(cmap, plan, follow(plan.path, 0), max_m=max_m, max_s=max_s)
