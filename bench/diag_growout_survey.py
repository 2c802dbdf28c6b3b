"""Why the grow-out's surveys read heavy (issue 10): the carriage's stills as the grow-out renders
them, measured as the survey stop measures them, against the renderer's truth. Prints one JSON object.

Stills as ``devices.sim.stereo_camera.TankView`` makes them for ``hil_tests/growout.py``: 640x480 a
view (focal 1400 px at 1280 scaled with the width), sea bream of one tank's mean weight with the
stock's weight CV (lognormal, ``devices.sim.stock``) turned into the renderer's normal lengths,
10-18 fish a still, both views side by side through a JPEG q95 4:4:4 round trip (the MJPEG server),
measured by ``vision.survey.measure_pair`` with the species' survey setup, 16 pairs a survey, the
stop's outlier rule (``controller.surveys.stop.implausible``) and its mean of a L^b.

Per mean weight: ``survey`` (each survey's mean weight error against the tank's mean weight, and
against the mean of the fish the stills showed), ``fish`` (every report matched to its rendered fish
as bench_survey_underwater.assign matches them: length error by the fish's length in the image (px,
mean of the views), and what each end contributes along the fish's axis, px, outward positive),
``selection`` (the found fish's true lengths against every fully visible one's) and ``wild`` (reports
matching no fish, and matched ones more than 10 % off). ``decomposition`` splits each weight's mean
survey error into per-fish bias on the found fish, size selection, and the rest (wild reports and
the outlier rule).

Run: ``.venv/bin/python bench/diag_growout_survey.py [--weights 12,20,35,60,100,150] [--surveys 6]
[--seed0 200000] [--pairs 16] [--size 640x480] [--params "good_length_px=1.0"]`` (tune on seeds >= 200000).
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench.bench_survey_underwater import assign, parse_params  # noqa: E402
from bench.diag_length_bias import end_errors  # noqa: E402
from controller.surveys.species import survey_species  # noqa: E402
from devices.sim.fish_scene import underwater_rig, underwater_scene  # noqa: E402
from vision.survey import measure_pair  # noqa: E402
from vision.survey_stats import implausible  # noqa: E402
from vision.underwater import measure_underwater  # noqa: E402

SPECIES = "sparus_aurata"
WEIGHT_CV = 0.20            # devices.sim.stock's weight_cv_pct at the start
PX_BINS = (0.0, 40.0, 60.0, 80.0, 120.0, 160.0, np.inf)


def tank_sizes(rng: np.random.Generator, mean_g: float, a: float, b: float) -> tuple[float, float]:
    """(mean fork length cm, length CV) of a stock of lognormal weights, as TankView._sizes draws them."""
    sd = np.sqrt(np.log1p(WEIGHT_CV ** 2))
    w = mean_g * np.exp(rng.normal(-sd * sd / 2, sd, 256))
    lengths = (w / a) ** (1 / b)
    return float(lengths.mean()), float(lengths.std() / lengths.mean())


def served(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pair through the MJPEG server's JPEG (q95, 4:4:4) and back, split again."""
    ok, buf = cv2.imencode(".jpg", np.hstack([left, right]), [cv2.IMWRITE_JPEG_QUALITY, 95,
                                                              cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                                                              cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444])
    img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    w = left.shape[1]
    return img[:, :w], img[:, w:]


def survey(seed: int, mean_g: float, rig, setup, sp, pairs: int, params=None) -> dict:
    """One survey of ``pairs`` stills: its reports, their truths and the survey stop's mean."""
    rng = np.random.default_rng(seed)
    length, cv = tank_sizes(rng, mean_g, sp.weight.a, sp.weight.b)
    calib = rig.calibration()
    reports, shown = [], []
    for _ in range(pairs):
        n = int(rng.integers(10, 19))
        sc = underwater_scene(rng, rig, n_fish=n, jpeg_quality=None, species=SPECIES, mean_length_cm=length,
                              length_cv=cv)
        left, right = served(sc.left, sc.right)
        fish = measure_pair(left, right, calib, setup) if params is None else \
            measure_underwater(left, right, calib, setup, params=params)
        vis = [t for t in sc.fish if t.fully_visible]
        shown += [t.weight_g for t in vis]
        matched = {k: ti for k, ti, _, _ in assign(fish, sc.fish, sc.rig.centres[0])}
        found = set(matched.values())
        for k, f in enumerate(fish):
            mid = (np.asarray(f.snout_mm) + np.asarray(f.fork_mm)) / 2
            row = {"length_cm": f.length_cm, "score": float(f.score),
                   "px": float(np.mean(np.linalg.norm(f.snout_px - f.fork_px, axis=1))),
                   "range_mm": float(np.linalg.norm(mid - sc.rig.centres[0]))}
            ti = matched[k]
            if ti >= 0:
                t = sc.fish[ti]
                e = end_errors(f, t)
                row |= {"true_cm": t.length_cm, "view_px": float(np.mean(e["len_px"])),
                        "snout_along": float(np.mean(e["snout_along"])), "fork_along": float(np.mean(e["fork_along"]))}
            reports.append(row)
        for i, t in enumerate(sc.fish):
            if t.fully_visible:
                px = float(np.mean(np.linalg.norm(t.snout_px - t.fork_px, axis=1)))
                reports.append({"visible_cm": t.length_cm, "visible_px": px, "found": i in found})
    lengths = np.array([r["length_cm"] for r in reports if "length_cm" in r])
    far = implausible(lengths) if len(lengths) else np.zeros(0, bool)
    w = sp.weight.weight_g(lengths[~far])
    mean = float(w.mean()) if len(w) else float("nan")
    return {"reports": reports, "mean_g": mean, "n": int((~far).sum()), "rejected": int(far.sum()),
            "cuts": cuts(reports, sp, float(calib.K1[0, 0])),
            "shown_mean_g": float(np.mean(shown)) if shown else float("nan")}


CUT_PX = (40.0, 50.0, 60.0, 80.0)


def cuts(reports: list[dict], sp, focal: float) -> dict:
    """The survey's mean weight keeping only fish (a) at least ``p`` px long in the image, (b) near
    enough that a fish of the survey's median length would be (a cut on range alone does not
    select on length)."""
    rows = [r for r in reports if "length_cm" in r]
    if not rows:
        return {}
    L = np.array([r["length_cm"] for r in rows])
    keep = ~implausible(L)
    px = np.array([r["px"] for r in rows])
    rng_mm = np.array([r["range_mm"] for r in rows])
    med = float(np.median(L[keep])) if keep.any() else float("nan")
    out = {}
    for p in CUT_PX:
        for name, sel in (("px", px >= p), ("range", focal * 10 * med / rng_mm >= p)):
            k = keep & sel
            out[f"{name}{int(p)}"] = [float(sp.weight.weight_g(L[k]).mean()) if k.any() else float("nan"), int(k.sum())]
    return out


def _stat(v) -> dict:
    v = np.asarray(v, float)
    if len(v) == 0:
        return {"n": 0}
    return {"n": len(v), "mean": round(float(v.mean()), 2), "median": round(float(np.median(v)), 2),
            "se": round(float(v.std(ddof=1) / np.sqrt(len(v))), 2) if len(v) > 1 else None}


def fish_bins(rows: list[dict]) -> dict:
    out = {}
    for lo, hi in zip(PX_BINS[:-1], PX_BINS[1:], strict=True):
        sel = [r for r in rows if lo <= r["view_px"] < hi]
        if sel:
            name = f"{int(lo)}-{int(hi)}" if np.isfinite(hi) else f"{int(lo)}+"
            out[name] = {"len_pct": _stat([100 * (r["length_cm"] / r["true_cm"] - 1) for r in sel]),
                         "snout_along_px": _stat([r["snout_along"] for r in sel]),
                         "fork_along_px": _stat([r["fork_along"] for r in sel])}
    return out


def one_weight(mean_g: float, surveys: int, seed0: int, rig, setup, sp, pairs: int, params=None) -> dict:
    runs = [survey(seed0 + k, mean_g, rig, setup, sp, pairs, params) for k in range(surveys)]
    rows = [r for s in runs for r in s["reports"]]
    matched = [r for r in rows if "true_cm" in r]
    reported = [r for r in rows if "length_cm" in r]
    visible = [r for r in rows if "visible_cm" in r]
    wa, wb = sp.weight.a, sp.weight.b
    wt = lambda cm: wa * np.asarray(cm, float) ** wb  # noqa: E731
    found_cm = [r["visible_cm"] for r in visible if r["found"]]
    vis_cm = [r["visible_cm"] for r in visible]
    wild = [r for r in reported if "true_cm" not in r]
    off = [r for r in matched if abs(r["length_cm"] / r["true_cm"] - 1) > 0.10]
    # the survey's mean weight error, split: a L^b of the matched reports against a L^b of their true
    # lengths (per-fish bias), a L^b of the found fish's true lengths against every visible fish's
    # (selection), a L^b of every visible fish against the tank's mean (the renderer's sizes); the
    # rest is what the wild reports and the outlier rule add
    bias = 100 * (wt([r["length_cm"] for r in matched]).mean() / wt([r["true_cm"] for r in matched]).mean() - 1)
    selection = 100 * (wt(found_cm).mean() / wt(vis_cm).mean() - 1) if found_cm else float("nan")
    rendered = 100 * (wt(vis_cm).mean() / mean_g - 1)
    errs = [100 * (s["mean_g"] / mean_g - 1) for s in runs]
    cut = {}
    for key in runs[0]["cuts"]:
        e = [100 * (s["cuts"][key][0] / mean_g - 1) for s in runs if s["cuts"] and np.isfinite(s["cuts"][key][0])]
        cut[key] = {"mean_err_pct": _stat(e), "fish": round(float(np.mean([s["cuts"][key][1] for s in runs
                                                                              if s["cuts"]])), 1)}
    return {"mean_g": mean_g, "surveys": surveys, "cuts": cut,
            "survey": {"mean_err_pct": _stat(errs), "vs_shown_pct": _stat([100 * (s["mean_g"] / s["shown_mean_g"] - 1)
                                                                            for s in runs]),
                       "fish_per_survey": round(float(np.mean([s["n"] for s in runs])), 1),
                       "rejected_per_survey": round(float(np.mean([s["rejected"] for s in runs])), 2),
                       "each_pct": [round(e, 1) for e in errs]},
            "fish": {"matched": len(matched), "len_pct": _stat([100 * (r["length_cm"] / r["true_cm"] - 1)
                                                                for r in matched]),
                     "by_view_px": fish_bins(matched)},
            "selection": {"visible": len(vis_cm), "found": len(found_cm),
                          "found_vs_visible_len_pct": round(100 * (np.mean(found_cm) / np.mean(vis_cm) - 1), 2)
                          if found_cm else None,
                          "recall_by_view_px": {f"{int(lo)}-{int(hi) if np.isfinite(hi) else 'inf'}":
                                                _recall(visible, lo, hi) for lo, hi in
                                                zip(PX_BINS[:-1], PX_BINS[1:], strict=True)}},
            "wild": {"unmatched": len(wild), "unmatched_len_over_median": [round(r["length_cm"] / float(
                np.median([x["length_cm"] for x in reported])), 2) for r in wild],
                "matched_over_10pct": len(off), "reports": len(reported)},
            "decomposition_pct": {"per_fish_bias": round(bias, 2), "selection": round(selection, 2),
                                  "rendered_vs_tank": round(rendered, 2),
                                  "survey_mean": round(float(np.mean(errs)), 2),
                                  "rest": round(float(np.mean(errs)) - bias - selection - rendered, 2)}}


def _recall(visible: list[dict], lo: float, hi: float) -> dict:
    sel = [r["found"] for r in visible if lo <= r["visible_px"] < hi]
    return {"visible": len(sel), "recall": round(float(np.mean(sel)), 3) if sel else None}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--weights", default="12,20,35,60,100,150")
    ap.add_argument("--surveys", type=int, default=6)
    ap.add_argument("--seed0", type=int, default=200000)
    ap.add_argument("--pairs", type=int, default=16)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--params", default="", help="vision.underwater.Params fields, e.g. 'min_score=0.04'")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    w, h = (int(x) for x in args.size.split("x"))
    rig = underwater_rig(image_size=(w, h), focal_px=1400.0 * w / 1280)
    sp = survey_species(SPECIES)
    setup = sp.setup("underwater", None)
    out = {"size": args.size, "seed0": args.seed0, "surveys": args.surveys, "pairs": args.pairs, "weights": []}
    for k, g in enumerate(float(x) for x in args.weights.split(",")):
        out["weights"].append(one_weight(g, args.surveys, args.seed0 + 1000 * k, rig, setup, sp, args.pairs,
                                         parse_params(args.params)))
    out["load"] = os.getloadavg()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
