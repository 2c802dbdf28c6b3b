"""From ``[cleaning]`` to a running cleaner: everything checked before anything starts.

``prepare(cfg)`` checks the section as a whole — the pond's geometry (coverage's ``pond_geometry``:
self-intersection, keep-outs outside the pond...), the dock on the floor the robot can reach,
TOWER.json a usable homography, ``[cleaning.float]`` keys FloatParams knows — and plans the
coverage path; every fault is ``BadInput`` naming file, key and fault (exit 2). ``build(...)``
then takes the ledger's progress up and wires the coordinator.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.errors import BadInput


@dataclass(frozen=True)
class Prepared:
    settings: object          # CleaningConfig
    geometry: object          # PondGeometry
    plan: object              # CoveragePlan
    H: np.ndarray
    float_params: object      # FloatParams
    fingerprint: str
    frame_size: tuple[int, int] | None = None   # the frames TOWER.json was fitted to (its image_size)


def float_params(values: dict, where: str):
    """``[cleaning.float]`` as FloatParams: an unknown key or a bad value names its key."""
    from vision.float_detect import FloatParams
    known = {f.name for f in dataclasses.fields(FloatParams)}
    for key in values:
        if key not in known:
            raise BadInput(where, f"cleaning.float.{key}", "unknown key")

    def tuples(v):
        return tuple(tuples(x) for x in v) if isinstance(v, list) else v
    try:
        return FloatParams(**{k: tuples(v) for k, v in values.items()})
    except (TypeError, ValueError) as exc:
        key, _, why = str(exc).partition(": ")
        if key in known:
            raise BadInput(where, f"cleaning.float.{key}", why) from None
        raise BadInput(where, "cleaning.float", str(exc)) from None


def fingerprint(settings) -> str:
    """What the map and the path index mean: a change here starts a fresh map."""
    from controller.cleaning.coverage import KEEPOUT_MARGIN
    keys = {"outline": settings.outline, "keepouts": settings.keepouts, "dock": settings.dock,
            "brush_m": settings.brush_m, "body_radius_m": settings.body_radius_m, "cell_m": settings.cell_m,
            "overlap": settings.overlap}
    if settings.keepout_margin_m != KEEPOUT_MARGIN:       # the default leaves older maps' fingerprints as they were
        keys["keepout_margin_m"] = settings.keepout_margin_m
    return hashlib.sha256(json.dumps(keys, sort_keys=True).encode()).hexdigest()[:16]


def _tower_file(name: str, where: str) -> str:
    """TOWER.json as ``[feeding] tables`` are found: beside farm.toml first, then from the working
    directory (the demo's ``config/TOWER.json``); a copied farm run from elsewhere failed with a bare
    'config/TOWER.json: no such file'."""
    path = Path(name)
    beside = Path(where).parent / path
    if not path.is_absolute() and beside.is_file():
        return str(beside)
    if path.exists() or path.is_absolute():
        return name
    raise BadInput(where, "cleaning.tower", f"{name}: no such file (looked beside {Path(where).name} and in "
                                            "the working directory)")


def prepare(cfg) -> Prepared:
    from shapely.geometry import Point

    from controller.cleaning.coverage import plan_coverage
    from controller.cleaning.geometry import pond_geometry
    s, where = cfg.cleaning, cfg.path
    geom = pond_geometry(s.outline, s.keepouts, where=where, key="cleaning.outline")
    if not geom.free(s.body_radius_m).buffer(1e-6).covers(Point(s.dock)):
        raise BadInput(where, "cleaning.dock", f"({s.dock[0]:g}, {s.dock[1]:g}) is not on the floor a robot of "
                                               f"radius {s.body_radius_m:g} m can reach")
    from controller.cli.track_cmd import load_tower_file  # the one reader of TOWER.json, `fishfarm track`'s
    H, frame_size = load_tower_file(_tower_file(s.tower, where))
    params = float_params(s.detection, where)
    plan = plan_coverage(geom, brush_m=s.brush_m, body_radius_m=s.body_radius_m, overlap=s.overlap,
                         keepout_margin_m=s.keepout_margin_m, start_xy=s.dock, where=where, key="cleaning")
    return Prepared(s, geom, plan, H, params, fingerprint(s), frame_size)


def build(prep: Prepared, camera, thrusters, store, clock, publish, *, alarms, lane, reopen=None):
    """The coordinator, taken up where the ledger left it (ledger.resume)."""
    from controller.cleaning import mopup
    from controller.cleaning.cleaner import Cleaner, Course
    from controller.cleaning.coverage import Router
    from controller.cleaning.coverage_map import CoverageMap
    from controller.cleaning.geofence import Geofence
    from controller.cleaning.ledger import resume
    from controller.cleaning.recovery import Recovery
    from controller.cleaning.steering import PathFollower
    from vision.float_detect import detect_float
    from vision.float_track import FloatTracker

    s, geom = prep.settings, prep.geometry
    free = geom.free(s.body_radius_m)
    router = Router(free)
    drive, mop_router = mopup.spaces(geom, s.body_radius_m, s.keepout_margin_m)

    def follow(path, start):
        return PathFollower(path, lookahead_m=s.lookahead_m, cruise=s.cruise, start_index=start)

    def mop_up(cmap, x, y):
        return mopup.begin(cmap, drive, mop_router, (x, y), follow, brush_m=s.brush_m,
                           spacing_m=s.brush_m * (1 - s.overlap), max_m=s.mopup_max_m, max_s=s.mopup_max_s)
    map_args = dict(cell_m=s.cell_m, brush_m=s.brush_m, body_radius_m=s.body_radius_m)
    course = Course(
        follow=follow, mop_up=mop_up if s.mopup_max_m > 0 else None,
        fresh_map=lambda: CoverageMap(geom, **map_args),
        route_home=lambda x, y: np.array(router.route((x, y), s.dock)),
        fingerprint=prep.fingerprint, save_every_s=s.save_every_s, publish_every_s=s.publish_every_s)
    back = resume(store, course, prep.plan, lambda data: CoverageMap.from_bytes(geom, data, **map_args),
                  estop_standing="estop" in alarms.active, autostart=s.autostart)

    def detector(image, near, scan=False):
        return detect_float(image, prep.H, prep.float_params, near=near, scan=scan)
    fence = Geofence.for_pond(geom, s.body_radius_m)
    return Cleaner(camera, thrusters, detector, FloatTracker(lost_after_s=s.lost_after_s), prep.plan,
                   back.follower, back.map, store, clock, publish, alarms=alarms, lane=lane, course=course,
                   run=back.run, state=back.state, mission=back.mission, reopen=reopen,
                   fence=fence, recovery=Recovery(after_s=s.recover_after_s, gaps=fence.gaps),
                   frame_size=prep.frame_size)
