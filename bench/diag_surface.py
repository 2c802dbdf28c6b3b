"""Where the surface setup loses its fish: the loss per stage on rendered nursery tanks.

Run: ``.venv/bin/python bench/diag_surface.py [--scenes 30] [--seed 1000]``; prints one JSON object.
Scenes and setup as bench/bench_survey_surface.py. For every fully visible fish (the recall's
denominator) the stages it passes, in order (``stages``: how many fish are still in at each):

  left_region / right_region  a fish found in that view whose ends lie within 25 % of the true
                              length of the true ends (either way round): the region exists;
  left_ends / right_ends      its snout and fork each within 3 % of the true pixel length of the
                              true pixels, head at the snout (the bench's image tolerance);
  paired                      a stereo pairing joins this fish's left and right regions;
  image_ok                    the paired, refined end pixels within 3 % in both views;
  solid_ok                    the 3-D ends each within 3 % of the length of the true ends (the
                              bench's rule), before the score cut;
  reported_ok                 the same, reported (``vision.surface.reported``: both scores' floors).

``each_stage_alone``: how many fish pass each stage whatever happened before it (e.g. right_ends
with the left view failed).

Also: the reports' failures by kind (a pairing of two different fish, a region that is no fish,
ends misplaced in an image, only the 3-D wrong); how the ends miss in each view (short of the true
end along the body, or past it); and, for the fish right in both images, the 3-D error of each end
in the fish's own frame (along the body, sideways, up), per cent of the length: a bias there is
depth, not the images.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from devices.sim.fish_scene import surface_scene  # noqa: E402
from devices.sim.fish_species import SPECIES  # noqa: E402
from vision.surface import reported, surface_stages  # noqa: E402
from vision.survey_types import FishGeometry, SurveySetup  # noqa: E402

TOL = 0.03
REGION_TOL = 0.25
STAGES = ("visible", "left_region", "left_ends", "right_region", "right_ends", "paired", "image_ok",
          "solid_ok", "reported_ok")


def _view_err(f, t, v):
    """(same-way error, swapped error) of a 2-D fish against truth t in view v, / true pixel length."""
    L = np.linalg.norm(t.snout_px[v] - t.fork_px[v])
    same = max(np.linalg.norm(f.snout - t.snout_px[v]), np.linalg.norm(f.fork - t.fork_px[v])) / L
    swap = max(np.linalg.norm(f.snout - t.fork_px[v]), np.linalg.norm(f.fork - t.snout_px[v])) / L
    return same, swap


def _assign(found, truth, v):
    """Per 2-D fish: (truth index or -1, same-way error)."""
    out = []
    for f in found:
        errs = [_view_err(f, t, v) for t in truth]
        if not errs:
            out.append((-1, np.inf))
            continue
        k = int(np.argmin([min(e) for e in errs]))
        out.append((k, errs[k][0]) if min(errs[k]) < REGION_TOL else (-1, np.inf))
    return out


def _ok3d(m, t) -> bool:
    L = np.linalg.norm(t.snout_mm - t.fork_mm)
    return bool(max(np.linalg.norm(m.snout_mm - t.snout_mm), np.linalg.norm(m.fork_mm - t.fork_mm)) <= TOL * L)


def _ok_img(m, t) -> bool:
    ok = True
    for v in (0, 1):
        L = np.linalg.norm(t.snout_px[v] - t.fork_px[v])
        ok &= np.linalg.norm(m.snout_px[v] - t.snout_px[v]) <= TOL * L
        ok &= np.linalg.norm(m.fork_px[v] - t.fork_px[v]) <= TOL * L
    return bool(ok)


def _end_miss(f, t, v):
    """How each end misses in view v, per cent of the true pixel length: along the body (+ = past
    the true end, outwards) and across it."""
    a, b = t.snout_px[v], t.fork_px[v]
    L = np.linalg.norm(a - b)
    e = (a - b) / L
    n = np.array([-e[1], e[0]])
    ds, dk = f.snout - a, f.fork - b
    return 100 * np.array([ds @ e, ds @ n, -(dk @ e), dk @ n]) / L


def _frame3d(m, t, up):
    L = np.linalg.norm(t.snout_mm - t.fork_mm)
    e = (t.snout_mm - t.fork_mm) / L
    u = up - (up @ e) * e
    u /= np.linalg.norm(u)
    s = np.cross(u, e)
    out = []
    for got, true in ((m.snout_mm, t.snout_mm), (m.fork_mm, t.fork_mm)):
        d = got - true
        out += [100 * d @ e / L, 100 * d @ s / L, 100 * d @ u / L]
    return out


def run(scenes: int, seed: int) -> dict:
    cv2.setNumThreads(1)
    stages = dict.fromkeys(STAGES, 0)
    alone = dict.fromkeys(STAGES, 0)     # each stage on its own, not after the ones before
    fails = {"reported": 0, "ok": 0, "no_region": 0, "cross_paired": 0, "ends_in_images": 0, "depth_only": 0,
             "duplicate": 0}
    misses = {"left": [], "right": []}
    frame3d = []
    up = np.array([0.0, 0.0, 1.0])
    for k in range(scenes):
        sc = surface_scene(np.random.default_rng(seed + k))
        calib = sc.rig.calibration()
        sp = SPECIES[sc.conditions["species"]]
        setup = SurveySetup(setup="surface", up_world=(0.0, 0.0, 1.0),
                            geometry=FishGeometry(fin_base_to_fork=sp.body_end))
        st = surface_stages(sc.left, sc.right, calib, setup)
        truth = sc.fish
        al, ar = _assign(st["left"], truth, 0), _assign(st["right"], truth, 1)
        for side, assign, found, v in (("left", al, st["left"], 0), ("right", ar, st["right"], 1)):
            for (ti, err), f in zip(assign, found, strict=True):
                if ti >= 0 and truth[ti].fully_visible and err > TOL:
                    misses[side].append(_end_miss(f, truth[ti], v))
        by_pair = {}
        for m, pk in zip(st["measured"], st["measured_pair"], strict=True):
            by_pair[pk] = m
        hit = set()
        for pk, (i, j) in enumerate(st["pairs"]):
            m = by_pair.get(pk)
            if m is None or not reported(m):
                continue
            fails["reported"] += 1
            ti, tj = al[i][0], ar[j][0]
            if ti < 0 and tj < 0:
                fails["no_region"] += 1
            elif ti != tj:
                fails["cross_paired"] += 1
            elif _ok3d(m, truth[ti]):
                fails["ok" if ti not in hit else "duplicate"] += 1
                hit.add(ti)
            elif not _ok_img(m, truth[ti]):
                fails["ends_in_images"] += 1
            else:
                fails["depth_only"] += 1
        for ti, t in enumerate(truth):
            if not t.fully_visible:
                continue
            passed = {"visible": True}
            passed["left_region"] = any(a == ti for a, _ in al)
            passed["left_ends"] = any(a == ti and e <= TOL for a, e in al)
            passed["right_region"] = any(a == ti for a, _ in ar)
            passed["right_ends"] = any(a == ti and e <= TOL for a, e in ar)
            ms = [(by_pair.get(pk)) for pk, (i, j) in enumerate(st["pairs"]) if al[i][0] == ti and ar[j][0] == ti]
            passed["paired"] = bool(ms)
            ms = [m for m in ms if m is not None]
            passed["image_ok"] = any(_ok_img(m, t) for m in ms)
            passed["solid_ok"] = any(_ok3d(m, t) for m in ms)
            passed["reported_ok"] = any(_ok3d(m, t) and reported(m) for m in ms)
            for m in ms:
                if _ok_img(m, t):
                    frame3d.append(_frame3d(m, t, up))
            for name in STAGES:
                alone[name] += bool(passed[name])
            for name in STAGES:           # cumulative: a fish counts at a stage only if it passed all before
                if not passed[name]:
                    break
                stages[name] += 1
    f3 = np.array(frame3d).reshape(-1, 6)
    names = ["snout_along", "snout_side", "snout_up", "fork_along", "fork_side", "fork_up"]
    miss = {}
    for side, rows in misses.items():
        a = np.array(rows).reshape(-1, 4)
        miss[side] = {"n": len(a),
                      "snout_short": int(np.sum(a[:, 0] < -100 * TOL)), "snout_long": int(np.sum(a[:, 0] > 100 * TOL)),
                      "fork_short": int(np.sum(a[:, 2] < -100 * TOL)), "fork_long": int(np.sum(a[:, 2] > 100 * TOL)),
                      "side_off": int(np.sum(np.maximum(np.abs(a[:, 1]), np.abs(a[:, 3])) > 100 * TOL))}
    err3d = {q: dict(zip(names, np.round(np.percentile(f3, p, axis=0), 2).tolist(), strict=True)) if len(f3) else {}
             for q, p in (("p25", 25), ("median", 50), ("p75", 75))}
    return {"scenes": scenes, "seed": seed, "stages": stages, "each_stage_alone": alone, "reports": fails,
            "end_misses": miss, "err3d_pct_of_length_image_ok": {"n": len(f3), **err3d}}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=30)
    ap.add_argument("--seed", type=int, default=1000)
    args = ap.parse_args()
    print(json.dumps(run(args.scenes, args.seed)))


if __name__ == "__main__":
    main()
