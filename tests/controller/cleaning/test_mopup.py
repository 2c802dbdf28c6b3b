"""The mop-up (controller/cleaning/mopup.py) on generated dirty maps: a map cleaned everywhere but
for seeded patches — lane gaps along the lanes, blobs, and a sliver hugging a keep-out inside the
plan's margin — laid out from the pond's geometry, not from the planner. Driven exactly, its path
brushes every patch it can reach and never leaves the space the plan itself keeps to; the cap
holds; its account survives a restart through the map's bytes; a pass gone by with its cells still
dirty gives them up for good, logged once."""
from __future__ import annotations

import logging
import math

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString

from controller.cleaning import mopup
from controller.cleaning.coverage import Router, drivable
from controller.cleaning.coverage_map import CoverageMap
from controller.cleaning.geometry import disc, pond_geometry
from controller.cleaning.steering import PathFollower

BRUSH, BODY, MARGIN, CELL = 0.5, 0.35, 0.10, 0.1
SPACING = BRUSH * 0.95
GEOM = pond_geometry([(0, 0), (12, 0), (12, 8), (0, 8)], [[(3, 3), (4, 3), (4, 4), (3, 4)], disc(8.5, 5, 0.7)])
FREE = GEOM.free(BODY)
DRIVE = drivable(GEOM, FREE, BODY, MARGIN)
ROUTER = Router(FREE, DRIVE)


def clean_map() -> CoverageMap:
    m = CoverageMap(GEOM, cell_m=CELL, brush_m=BRUSH, body_radius_m=BODY)
    m.first_m[...] = 0.0
    m.odometer_m = 100.0
    return m


def cell_xy(m, rows, cols):
    return np.c_[m.origin[0] + (cols + 0.5) * CELL, m.origin[1] + (rows + 0.5) * CELL]


def dirty_patches(m, rng, n):
    """``n`` patches of dirt, each 1-2 cells across and 0.3-2 m long along x or y (lane gaps), or a
    blob up to 0.6 m square, placed where a robot centre of the plan's space 0.3 m off would brush
    them; returns their flat cell indices."""
    rows, cols = m.first_m.shape
    far = DRIVE.buffer(-0.3)
    out = []
    while len(out) < n:
        kind = rng.integers(3)
        length = int(rng.integers(3, 20))
        w, h = [(length, int(rng.integers(1, 3))), (int(rng.integers(1, 3)), length),
                (int(rng.integers(2, 6)), int(rng.integers(2, 6)))][kind]
        r0, c0 = int(rng.integers(0, rows - h)), int(rng.integers(0, cols - w))
        rr, cc = np.mgrid[r0:r0 + h, c0:c0 + w]
        xy = cell_xy(m, rr.ravel(), cc.ravel())
        if not shapely.contains_xy(far, xy[:, 0], xy[:, 1]).all():
            continue
        flat = np.ravel_multi_index((rr.ravel(), cc.ravel()), (rows, cols))
        if any(np.intersect1d(flat, o).size for o in out):
            continue
        m.first_m.flat[flat] = np.inf
        out.append(flat)
    return out


def drive_exactly(m, path):
    """The brush along the path, heading along it."""
    for a, b in zip(path, path[1:], strict=False):
        m.sweep(*a, *b)


@pytest.mark.parametrize("seed", range(6))
def test_the_plan_driven_brushes_every_generated_patch_and_stays_in_the_plans_space(seed):
    rng = np.random.default_rng(seed)
    m = clean_map()
    patches = dirty_patches(m, rng, int(rng.integers(1, 7)))
    start = np.array([0.6, 0.6])
    plan = mopup.plan_mopup(m, DRIVE, ROUTER, start, brush_m=BRUSH, spacing_m=SPACING, max_m=1000.0, min_yield=0)
    assert np.allclose(plan.path[0], start)
    assert plan.aimed == sum(len(p) for p in patches) and plan.out_of_reach == 0
    for p in plan.passes:                        # the passes keep the plan's margin round keep-outs
        assert DRIVE.buffer(1e-6).covers(LineString([p.a, p.b]))
    assert FREE.buffer(1e-6).covers(LineString(plan.path))      # travel: the body never touches anything
    steps = np.hypot(*np.diff(plan.path, axis=0).T)
    assert steps.max() <= 0.25 + 1e-9 and plan.length_m == pytest.approx(steps.sum(), abs=1e-6)
    drive_exactly(m, plan.path)
    for p in patches:
        assert m.cleaned().flat[p].all()


@pytest.mark.parametrize("tilt", [0, 1, -1])
def test_a_strip_by_a_wall_brushed_only_from_the_edge_of_the_plans_space_is_mopped(tilt):
    """An outside tester's L-shaped pond: a strip of cells 0.25 m from a wall, brushed only by a
    centre at the edge of the space the plan keeps to (a few cm wide there), one cell of it a step
    off the line: the passes ran along the cells' tilted axis, cut only that room's corners, and
    the strip was left "out of reach". Along each wall, with a cell a step off either way."""
    for wall in ("west", "south", "east", "north"):
        m = clean_map()
        k = np.arange(10, 21)
        rows, cols = {"west": (k, np.full_like(k, 2)), "east": (k, np.full_like(k, 117)),
                      "south": (np.full_like(k, 2), k + 40), "north": (np.full_like(k, 77), k + 40)}[wall]
        rows, cols = rows.copy(), cols.copy()
        inward = {"west": (0, 1), "east": (0, -1), "south": (1, 0), "north": (-1, 0)}[wall]
        if tilt:
            end = 0 if tilt > 0 else -1
            rows[end], cols[end] = rows[end] + inward[0], cols[end] + inward[1]
        xy = cell_xy(m, rows, cols)
        edge = DRIVE.boundary.distance(shapely.points(xy))
        assert np.all(edge < BRUSH / 2 - mopup.REACH_TOL) and not shapely.contains_xy(DRIVE, xy[:, 0], xy[:, 1]).any()
        flat = np.ravel_multi_index((rows, cols), m.first_m.shape)
        m.first_m.flat[flat] = np.inf
        plan = mopup.plan_mopup(m, DRIVE, ROUTER, (6.0, 4.0), brush_m=BRUSH, spacing_m=SPACING, max_m=1000.0,
                                min_yield=0)
        assert plan.aimed == len(flat) and plan.out_of_reach == 0, (wall, plan.aimed, plan.out_of_reach)
        for p in plan.passes:
            assert DRIVE.buffer(1e-6).covers(LineString([p.a, p.b]))
        drive_exactly(m, plan.path)
        assert m.cleaned().flat[flat].all(), wall


def test_dirt_out_of_the_plans_reach_and_specks_are_left_alone():
    m = clean_map()
    rows, cols = np.nonzero(m.reachable)
    xy = cell_xy(m, rows, cols)
    gap = shapely.distance(GEOM.keepouts[1], shapely.points(xy))
    sliver = gap < 0.22                          # brushed only by a body inside the plan's margin
    m.first_m[rows[sliver], cols[sliver]] = np.inf
    m.first_m[20, 20] = m.first_m[70, 100] = np.inf          # two lone cells: the map's noise
    plan = mopup.plan_mopup(m, DRIVE, ROUTER, (0.6, 0.6), brush_m=BRUSH, spacing_m=SPACING, max_m=1000.0)
    assert sliver.sum() > 20 and plan.passes == () and plan.aimed == 0
    assert plan.out_of_reach == sliver.sum() + 2


def test_the_plan_keeps_within_its_cap_and_takes_the_nearest_richest_dirt_first():
    m = clean_map()
    near = np.ravel_multi_index((np.full(15, 10), np.arange(10, 25)), m.first_m.shape)    # 1.5 m gap near
    far = np.ravel_multi_index((np.full(15, 70), np.arange(95, 110)), m.first_m.shape)     # the same far off
    m.first_m.flat[np.r_[near, far]] = np.inf
    whole = mopup.plan_mopup(m, DRIVE, ROUTER, (0.6, 0.6), brush_m=BRUSH, spacing_m=SPACING, max_m=1000.0,
                             min_yield=0)
    assert len(whole.passes) == 2 and np.intersect1d(whole.passes[0].cells, near).size == 15
    for cap in (0.0, 1.0, whole.length_m / 2, whole.length_m - 0.1):
        capped = mopup.plan_mopup(m, DRIVE, ROUTER, (0.6, 0.6), brush_m=BRUSH, spacing_m=SPACING, max_m=cap,
                                  min_yield=0)
        assert capped.length_m <= cap + 1e-9 and len(capped.passes) < 2


def test_a_patch_not_worth_its_way_is_left():
    m = clean_map()
    rich = np.ravel_multi_index((np.full(15, 12), np.arange(10, 25)), m.first_m.shape)    # 1.5 m gap near
    poor = np.ravel_multi_index((np.full(4, 70), np.arange(100, 104)), m.first_m.shape)   # 4 cells 10 m off
    m.first_m.flat[np.r_[rich, poor]] = np.inf
    plan = mopup.plan_mopup(m, DRIVE, ROUTER, (0.6, 0.6), brush_m=BRUSH, spacing_m=SPACING, max_m=1000.0)
    assert len(plan.passes) == 1 and set(plan.passes[0].cells) == set(rich)
    assert plan.length_m * mopup.MIN_YIELD <= len(rich)


def follow(path, start):
    return PathFollower(path, start_index=start)


def begin(m, xy, max_m=50.0, max_s=900.0):
    """Every patch worth its way (the generated ones lie far apart)."""
    return mopup.begin(m, DRIVE, ROUTER, xy, follow, brush_m=BRUSH, spacing_m=SPACING, max_m=max_m, max_s=max_s,
                       min_yield=0)


def ride(m, job, path, sweep=True, dt=0.1):
    """Poses along ``path`` (heading along it) to the mop-up; the brush sweeps between them."""
    out = None
    for a, b in zip(path, path[1:], strict=False):
        if sweep:
            m.sweep(*a, *b)
        out = job.command(*b, math.atan2(b[1] - a[1], b[0] - a[0]), dt_s=dt)
        if out is None:
            break
    return out


def test_a_restart_mid_mopup_plans_again_from_the_saved_map_with_what_is_left_of_the_cap():
    rng = np.random.default_rng(7)
    m = clean_map()
    dirty_patches(m, rng, 4)
    job = begin(m, (0.6, 0.6), max_m=60.0)
    half = job.plan.ends[1]
    ride(m, job, job.plan.path[:half + 1])
    assert not job.done and m.mopup["s"] > 0
    metres = m.mopup["m"]
    assert metres == pytest.approx(float(np.sum(np.hypot(*np.diff(job.plan.path[:half + 1], axis=0).T))), abs=0.3)
    saved = m.to_bytes()                                   # what the ledger holds at the kill
    back = CoverageMap.from_bytes(GEOM, saved, cell_m=CELL, brush_m=BRUSH, body_radius_m=BODY)
    assert back.mopup == m.mopup
    again = begin(back, job.plan.path[half])
    assert again.plan.length_m <= 60.0 - metres + 1e-9
    left = mopup.dirty(back).reshape(-1)
    aimed = np.concatenate([p.cells for p in again.plan.passes])
    assert left[aimed].all()                               # only what is still dirty
    assert again.plan.aimed + again.plan.out_of_reach == left.sum() and again.plan.out_of_reach <= 2   # specks
    assert ride(back, again, again.plan.path) is None and again.done
    assert mopup.dirty(back).sum() <= again.plan.out_of_reach
    ended = CoverageMap.from_bytes(GEOM, back.to_bytes(), cell_m=CELL, brush_m=BRUSH, body_radius_m=BODY)
    over = begin(ended, (5.0, 1.0))                         # over: nothing planned, nothing driven
    assert over.done and over.plan.passes == () and over.command(5.0, 1.0, 0.0, 0.1) is None


@pytest.mark.parametrize("cap", ["metres", "seconds"])
def test_the_cap_ends_the_mopup_and_stays_ended_across_a_restart(cap):
    rng = np.random.default_rng(3)
    m = clean_map()
    dirty_patches(m, rng, 5)
    job = begin(m, (0.6, 0.6), max_m=100.0, max_s=30.0)
    assert job.command(0.6, 0.6, 0.0, 0.1) is not None
    if cap == "metres":                 # the last process drove its plans to the cap, and was killed
        m.mopup["m"] = 100.0
        back = CoverageMap.from_bytes(GEOM, m.to_bytes(), cell_m=CELL, brush_m=BRUSH, body_radius_m=BODY)
        again = begin(back, (0.6, 0.6), max_m=100.0, max_s=30.0)
        assert again.plan.passes == () and again.done and mopup.dirty(back).any()
    else:
        m.mopup["s"] += 30.0
        assert job.command(0.6, 0.6, 0.0, 0.1) is None and job.done
    back = CoverageMap.from_bytes(GEOM, m.to_bytes(), cell_m=CELL, brush_m=BRUSH, body_radius_m=BODY)
    assert begin(back, (0.6, 0.6), max_m=100.0, max_s=30.0).command(0.6, 0.6, 0.0, 0.1) is None


def test_a_pass_gone_by_with_its_dirt_left_gives_it_up_for_good_logged_once(caplog):
    m = clean_map()
    gaps = [np.ravel_multi_index((np.full(12, r), np.arange(c, c + 12)), m.first_m.shape)
            for r, c in ((10, 10), (16, 30))]
    for g in gaps:
        m.first_m.flat[g] = np.inf
    job = begin(m, (0.6, 0.6))
    assert len(job.plan.passes) == 2
    first = job.plan.passes[0].cells
    with caplog.at_level(logging.WARNING, "fishfarm.cleaner"):
        ride(m, job, job.plan.path[:job.plan.ends[0] + 1], sweep=False)       # the fence kept it off
        ride(m, job, job.plan.path[job.plan.ends[0]:job.plan.ends[0] + 4])    # on its way to the next
        ride(m, job, job.plan.path[job.plan.ends[0] + 3:job.plan.ends[0] + 6])
    gave = [r for r in caplog.records if "gives up" in r.getMessage()]
    assert len(gave) == 1 and f"{len(first)} cells" in gave[0].getMessage()
    assert m.given_up.flat[first].all() and not m.given_up.flat[job.plan.passes[1].cells].any()
    back = CoverageMap.from_bytes(GEOM, m.to_bytes(), cell_m=CELL, brush_m=BRUSH, body_radius_m=BODY)
    again = begin(back, (3.0, 1.0))
    assert all(np.intersect1d(p.cells, first).size == 0 for p in again.plan.passes)


def test_a_stalled_pass_is_given_up_after_stall_s_and_a_stalled_last_one_ends_the_mopup(caplog):
    m = clean_map()
    for r, c in ((10, 10), (16, 30)):
        m.first_m.flat[np.ravel_multi_index((np.full(12, r), np.arange(c, c + 12)), m.first_m.shape)] = np.inf
    job = begin(m, (0.6, 0.6))
    assert len(job.plan.passes) == 2
    stuck = job.plan.path[1]                      # held short of its first pass (a standoff with the fence)
    ride(m, job, job.plan.path[:2], sweep=False)
    at = job.follower.progress
    with caplog.at_level(logging.WARNING, "fishfarm.cleaner"):
        for _ in range(round(mopup.STALL_S / 0.5) - 1):
            assert job.command(*stuck, 0.0, dt_s=0.5) is not None
        assert job.follower.progress == at        # not yet
        job.command(*stuck, 0.0, dt_s=0.5)
        job.command(*stuck, 0.0, dt_s=0.5)
    assert job.follower.progress == job.plan.ends[0] + 1 and not job.done
    assert m.given_up.flat[job.plan.passes[0].cells].all()
    assert any("stalled" in r.getMessage() for r in caplog.records)
    stuck = job.plan.path[job.plan.ends[0] + 1]
    out = [job.command(*stuck, 0.0, dt_s=0.5) for _ in range(round(mopup.STALL_S / 0.5) + 3)]
    assert out[-1] is None and job.done and m.mopup["done"]


def test_the_mopup_keeps_its_extra_margin_round_keepouts():
    drive, router = mopup.spaces(GEOM, BODY, MARGIN)
    m = clean_map()
    rows, cols = np.nonzero(m.reachable)
    xy = cell_xy(m, rows, cols)
    gap = np.min([shapely.distance(k, shapely.points(xy)) for k in GEOM.keepouts], axis=0)
    ring = (gap > 0.3) & (gap < 0.6)              # dirt round both keep-outs
    m.first_m[rows[ring], cols[ring]] = np.inf
    plan = mopup.plan_mopup(m, drive, router, (0.6, 0.6), brush_m=BRUSH, spacing_m=SPACING, max_m=1000.0,
                            min_yield=0)
    assert plan.passes
    least = BODY + MARGIN + mopup.EXTRA_MARGIN_M - 0.01
    for p in plan.passes:
        assert min(shapely.distance(k, LineString([p.a, p.b])) for k in GEOM.keepouts) >= least
