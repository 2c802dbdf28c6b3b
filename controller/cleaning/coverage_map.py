"""The coverage map: a grid of floor cells, each remembering when the brush first passed over it.

A cell (``cell_m`` square) counts as cleaned once the brush's swath covers its centre; it counts
in the coverage fraction when its centre lies in the reachable floor (geometry.py). Each cell
keeps the robot's odometer (metres driven) at the moment it was first cleaned, which makes the
overlap measure exact and cheap:

- a sweep's swath is the quadrilateral traced by the brush (a bar ``brush_m`` wide, square to
  the robot's heading, centred under it) from one pose to the next;
- it counts as overlapping when more than half its cells were cleaned earlier than the last
  ``brush_m`` of path (what the brush cleaned a moment ago, under itself, is not overlap); steps
  are judged together until they make at least one cell of path (a step shorter than a cell holds
  the centres of a few of the bar's cells only — of one row when the bar is a few degrees
  askew, as a crabbing robot's is — and judged alone, the row shared with the last lane would
  make a fifth of a clean lane "overlap");
- ``overlap()`` = length of overlapping sweeps / length of all sweeps.

``to_bytes``/``from_bytes`` carry the whole map through the store, so a restarted controller
resumes with what was cleaned and with the same overlap account — and with the mop-up's
(mopup.py): ``mopup`` (None before it begins; then the metres of its plans gone by, the farm
seconds it has run, whether it is over) and ``given_up``, the cells it gave up for good.
"""
from __future__ import annotations

import json
import math
import struct
import zlib

import cv2
import numpy as np
import shapely

from controller.cleaning.geometry import PondGeometry

MAGIC = b"FFCM1"
NEVER = np.float32(np.inf)
# image() grey levels
OUTSIDE, OUT_OF_REACH, DIRTY, CLEAN = 0, 60, 130, 255


class CoverageMap:
    def __init__(self, geom: PondGeometry, *, cell_m: float = 0.1, brush_m: float, body_radius_m: float):
        if not (cell_m > 0 and brush_m > 0 and body_radius_m > 0):
            raise ValueError(f"cell_m, brush_m, body_radius_m must be > 0: {cell_m}, {brush_m}, {body_radius_m}")
        self.cell_m, self.brush_m, self.body_radius_m = float(cell_m), float(brush_m), float(body_radius_m)
        minx, miny, maxx, maxy = geom.outline.bounds
        self.origin = (minx, miny)
        rows, cols = math.ceil((maxy - miny) / cell_m), math.ceil((maxx - minx) / cell_m)
        x, y = np.meshgrid(minx + (np.arange(cols) + 0.5) * cell_m, miny + (np.arange(rows) + 0.5) * cell_m)
        self.water = shapely.contains_xy(geom.water, x, y)
        self.reachable = shapely.contains_xy(geom.reachable(body_radius_m, brush_m), x, y)
        self.first_m = np.full((rows, cols), NEVER, np.float32)
        self.odometer_m = 0.0
        self.overlap_m = 0.0
        self._pending_m = 0.0                # length swept since the last judgement
        self._pending_cells = [0, 0]         # its cells: cleaned before, all
        self.given_up = np.zeros((rows, cols), bool)   # cells the mop-up will not try again
        self.mopup: dict | None = None       # {"m", "s", "done"} once the mop-up began

    def _cells(self, corners: np.ndarray):
        """Cells whose centre lies in the convex hull of the corners: (mask, its window) or None.
        (cv2.fillConvexPoly would be shorter, but it marks every cell an edge touches: +36 % area
        for a 0.5 m brush on 0.1 m cells, measured; coverage figures must not be flattered.)"""
        hull = cv2.convexHull(corners.astype(np.float32)).reshape(-1, 2).astype(float)
        rows, cols = self.first_m.shape
        lo = np.floor((hull.min(axis=0) - self.origin) / self.cell_m).astype(int)
        hi = np.ceil((hull.max(axis=0) - self.origin) / self.cell_m).astype(int) + 1
        c0, r0 = max(lo[0], 0), max(lo[1], 0)
        c1, r1 = min(hi[0], cols), min(hi[1], rows)
        if c1 <= c0 or r1 <= r0:
            return None, (0, 0, 0, 0)
        x = self.origin[0] + (np.arange(c0, c1) + 0.5) * self.cell_m
        y = self.origin[1] + (np.arange(r0, r1) + 0.5) * self.cell_m
        inside = np.ones((r1 - r0, c1 - c0), bool)
        edges = np.roll(hull, -1, axis=0) - hull
        orient = np.sign(np.sum(hull[:, 0] * np.roll(hull[:, 1], -1) - np.roll(hull[:, 0], -1) * hull[:, 1])) or 1.0
        for (vx, vy), (ex, ey) in zip(hull, edges, strict=True):
            inside &= orient * (ex * (y[:, None] - vy) - ey * (x[None, :] - vx)) >= -1e-12
        return inside, (r0, r1, c0, c1)

    def _swath(self, x0, y0, x1, y1, h0, h1) -> np.ndarray:
        half = self.brush_m / 2
        n0 = np.array([-math.sin(h0), math.cos(h0)]) * half
        n1 = np.array([-math.sin(h1), math.cos(h1)]) * half
        p0, p1 = np.array([x0, y0]), np.array([x1, y1])
        return np.array([p0 + n0, p1 + n1, p1 - n1, p0 - n0])

    def sweep(self, x0: float, y0: float, x1: float, y1: float,
              heading0: float | None = None, heading1: float | None = None) -> float:
        """The brush moved from pose 0 to pose 1: mark the swath. Headings default to the direction
        of travel (the brush's heading is the robot's, which a current makes differ from it).
        Returns the fraction of the swath's cells that were already cleaned (overlap)."""
        step = math.hypot(x1 - x0, y1 - y0)
        if heading0 is None:
            if step < 1e-9:
                return 0.0
            heading0 = heading1 = math.atan2(y1 - y0, x1 - x0)
        heading1 = heading0 if heading1 is None else heading1
        self.odometer_m += step
        self._pending_m += step
        cells, (r0, r1, c0, c1) = self._cells(self._swath(x0, y0, x1, y1, heading0, heading1))
        if cells is None or not cells.any():
            return 0.0                       # a step narrower than a cell: judged with the next one
        roi = self.first_m[r0:r1, c0:c1]
        seen = roi[cells]
        before = np.count_nonzero(seen < self.odometer_m - step - self.brush_m)
        roi[cells] = np.minimum(seen, np.float32(self.odometer_m))
        self._pending_cells[0] += int(before)
        self._pending_cells[1] += seen.size
        if self._pending_m >= self.cell_m:
            if self._pending_cells[0] > 0.5 * self._pending_cells[1]:
                self.overlap_m += self._pending_m
            self._pending_m, self._pending_cells = 0.0, [0, 0]
        return float(before) / seen.size

    def cleaned(self) -> np.ndarray:
        return np.isfinite(self.first_m)

    def coverage(self) -> float:
        """Cleaned reachable cells / reachable cells."""
        reach = np.count_nonzero(self.reachable)
        return float(np.count_nonzero(self.reachable & self.cleaned())) / reach if reach else 1.0

    def overlap(self) -> float:
        """Length of sweeps over floor already more than half cleaned / length swept (module docstring)."""
        return self.overlap_m / self.odometer_m if self.odometer_m > 0 else 0.0

    def image(self) -> np.ndarray:
        """uint8 grid, north (+y) up: 255 cleaned, 130 still to clean, 60 water out of reach, 0 not water."""
        img = np.where(self.water, OUT_OF_REACH, OUTSIDE).astype(np.uint8)
        img[self.reachable] = DIRTY
        img[self.cleaned() & (self.water | self.reachable)] = CLEAN
        return np.ascontiguousarray(img[::-1])

    def _header(self) -> dict:
        return {"shape": list(self.first_m.shape), "origin": list(self.origin), "cell_m": self.cell_m,
                "brush_m": self.brush_m, "body_radius_m": self.body_radius_m}

    def to_bytes(self) -> bytes:
        extra = {} if self.mopup is None else {"mopup": self.mopup,
                                               "given_up": np.flatnonzero(self.given_up).tolist()}
        head = json.dumps({**self._header(), "odometer_m": self.odometer_m, "overlap_m": self.overlap_m,
                           **extra}).encode()
        return MAGIC + struct.pack("<I", len(head)) + head + zlib.compress(self.first_m.tobytes(), 6)

    @classmethod
    def from_bytes(cls, geom: PondGeometry, data: bytes, *, cell_m: float = 0.1, brush_m: float,
                   body_radius_m: float) -> CoverageMap:
        """The map stored by ``to_bytes``. ValueError when it is not one, or was made for another
        pond, grid or robot (the caller then starts a fresh map)."""
        fresh = cls(geom, cell_m=cell_m, brush_m=brush_m, body_radius_m=body_radius_m)
        try:
            if data[:len(MAGIC)] != MAGIC:
                raise ValueError("not a coverage map")
            (n,) = struct.unpack_from("<I", data, len(MAGIC))
            head = json.loads(data[len(MAGIC) + 4:len(MAGIC) + 4 + n])
            grid = np.frombuffer(zlib.decompress(data[len(MAGIC) + 4 + n:]), np.float32)
            if {k: head[k] for k in fresh._header()} != json.loads(json.dumps(fresh._header())):
                raise ValueError("made for another pond, grid or robot")
            fresh.first_m[...] = grid.reshape(fresh.first_m.shape)
            fresh.odometer_m, fresh.overlap_m = float(head["odometer_m"]), float(head["overlap_m"])
            if head.get("mopup") is not None:          # older maps have none: the mop-up not begun
                m = head["mopup"]
                fresh.mopup = {"m": float(m["m"]), "s": float(m["s"]), "done": bool(m["done"])}
                fresh.given_up.flat[np.asarray(head.get("given_up", []), int)] = True
        except (struct.error, zlib.error, KeyError, TypeError, IndexError, json.JSONDecodeError) as exc:
            raise ValueError(f"stored coverage map unreadable: {exc}") from None
        return fresh
