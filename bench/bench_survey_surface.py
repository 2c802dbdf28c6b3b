"""Surface-setup accuracy and speed: nursery tanks seen from above, rendered with ground truth.

Run: ``.venv/bin/python bench/bench_survey_surface.py [--scenes 30] [--seed 1000]``; prints one JSON
object. Each scene is ``devices.sim.fish_scene.surface_scene`` with its conditions drawn from its own
seed (species, sizes, 5-20 fish, depth, lamps, glare, ripples, noise...), measured by
``vision.survey.measure_pair`` on one core (OpenCV and BLAS single-threaded).

Matching a reported fish to the truth: the truth fish whose snout and fork are both nearest in 3-D;
it is *correct* by the underwater bench's rule (bench/bench_survey_underwater.py, the same goals
judged the same way): the snout and the fork each within ``TOL`` (3 % of the true fork length, ~4 mm
for a 13 cm fish) across camera 1's line of sight and within ``TOL_DEPTH`` (10 %) along it --
depth is where stereo is weakest, and an end's depth error changes a level fish's length only to
second order (a fork 6 % of the length too deep: the length ~0.2 % long). *Head/tail swapped* when
that holds with snout and fork exchanged, else wrong. ``*_strict``: each end within 3 % in every
direction (at this rig's 200 mm baseline from 1.2 m a pixel of disparity is ~5 mm of depth, so the
strict rule asks for the ends' disparities to ~0.6 px); ``precision_image`` / ``recall_image``: the
same 3 % per end in each image instead.
Recall: correct reports / fully visible fish (snout, fork and body in both images, < 10 % hidden).
Precision: correct / reported. Head/tail rate: among reports matched to a fish either way round,
the share with the head at the snout. Weights: W = a L^b with the species' coefficients (what
config/species.toml gives the survey); per-fish MAPE against the truth fish's a L^b of its true fork
length (``model_weight_g``: the measurement's error) and against its weight with the individual's
condition scatter (``weight_g``: what a scale would say). Survey mean weight: mean over reported
fish vs mean over the fully visible fish, per scene and pooled. Score-vs-error: length error by
score quartile, and the Spearman rank correlation of score with |length error|. Times: per-stage
medians in ms per pair (process CPU time for the total; stages as measure_pair reports them).

The fork from above: the caudal fin stands edge-on and its notch is seldom seen, so the survey
places the fork from the fin base by the species' fin-base / fork-length ratio
(``FishGeometry.fin_base_to_fork``). The bench takes that ratio from the renderer's species table
(``body_end``), as a farm would measure it on a hand sample of its stock.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench.bench_survey_underwater import TOL_DEPTH, placement  # noqa: E402
from devices.sim.fish_scene import surface_scene  # noqa: E402
from devices.sim.fish_species import SPECIES  # noqa: E402
from vision.survey import measure_pair  # noqa: E402
from vision.survey_types import FishGeometry, SurveySetup  # noqa: E402

TOL = 0.03


def _match(m, fish, centre, strict: bool = False):
    """(truth index, 'ok' | 'swapped' | 'wrong', largest error of an end / length): the nearest
    truth fish either way round, judged by the rule in the module docstring."""
    best = (None, "wrong", np.inf)
    for i, t in enumerate(fish):
        L = np.linalg.norm(t.snout_mm - t.fork_mm)
        same = max(np.linalg.norm(m.snout_mm - t.snout_mm), np.linalg.norm(m.fork_mm - t.fork_mm)) / L
        swap = max(np.linalg.norm(m.snout_mm - t.fork_mm), np.linalg.norm(m.fork_mm - t.snout_mm)) / L
        for err, kind in ((same, "ok"), (swap, "swapped")):
            if err < best[2]:
                best = (i, kind, err)
    i, kind, err = best
    if i is not None and kind == "ok" and not strict:
        across, along = placement(m, fish[i], centre)
        fits = across <= TOL and along <= TOL_DEPTH
    else:
        fits = err <= TOL
    if not fits:
        kind = "swapped" if kind == "swapped" and err < 0.25 else "wrong"
    return i, kind, err


def _pct(x) -> float:
    return round(100 * float(x), 2)


def _in_images(m, t) -> bool:
    """Snout and fork each within TOL of the fish's pixel length of the true pixels, in both views."""
    ok = True
    for v in (0, 1):
        L = np.linalg.norm(t.snout_px[v] - t.fork_px[v])
        ok &= np.linalg.norm(m.snout_px[v] - t.snout_px[v]) <= TOL * L
        ok &= np.linalg.norm(m.fork_px[v] - t.fork_px[v]) <= TOL * L
    return bool(ok)


def _spearman(a, b):
    if len(a) < 3:
        return float("nan")
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def _baseline_ms(left, right) -> float:
    """The issue's yardstick, timed here in the same process: a full-frame bank of 12 rotated
    15x15 templates (cv2.matchTemplate) on both images of a pair (reading excluded)."""
    tmpl = np.zeros((15, 15), np.float32)
    tmpl[7, :] = 1.0
    bank = [cv2.warpAffine(tmpl, cv2.getRotationMatrix2D((7, 7), 15 * k, 1.0), (15, 15)) for k in range(12)]
    grey = [cv2.cvtColor(im, cv2.COLOR_BGR2GRAY).astype(np.float32) for im in (left, right)]
    t0 = time.process_time()
    for g in grey:
        for t in bank:
            cv2.matchTemplate(g, t, cv2.TM_CCORR)
    return 1000 * (time.process_time() - t0)


def run(scenes: int, seed: int, ratio: bool = True) -> dict:
    cv2.setNumThreads(1)
    visible = reported = correct = swapped = correct_img = correct_strict = 0
    scores, len_err, w_err, w_err_scatter, stage_ms, total_ms = [], [], [], [], {}, []
    w_err_all = []
    survey_est, survey_true, scene_mean_err, base_ms = [], [], [], []
    wrong_lengths, kept = [], []     # (score, correct, correct in the images) per report
    for k in range(scenes):
        sc = surface_scene(np.random.default_rng(seed + k))
        calib = sc.rig.calibration()
        sp = SPECIES[sc.conditions["species"]]
        setup = SurveySetup(setup="surface", up_world=(0.0, 0.0, 1.0),
                            geometry=FishGeometry(fin_base_to_fork=sp.body_end if ratio else None))
        timings: dict[str, float] = {}
        t0 = time.process_time()
        found = measure_pair(sc.left, sc.right, calib, setup, timings)
        total_ms.append(1000 * (time.process_time() - t0))
        base_ms.append(_baseline_ms(sc.left, sc.right))
        for name, s in timings.items():
            stage_ms.setdefault(name, []).append(1000 * s)
        vis = [t for t in sc.fish if t.fully_visible]
        visible += len(vis)
        est_w = []
        hit, hit_img, hit_strict = set(), set(), set()
        centre = sc.rig.centres[0]
        for m in found:
            reported += 1
            i, kind, err = _match(m, sc.fish, centre)
            if _match(m, sc.fish, centre, strict=True)[1] == "ok" and i not in hit_strict:
                correct_strict += 1
                hit_strict.add(i)
            w = sp.a * m.length_cm ** sp.b
            est_w.append(w)
            t = sc.fish[i]
            true_len = np.linalg.norm(t.snout_mm - t.fork_mm) / 10
            w_err_all.append(w / t.model_weight_g - 1)
            scores.append(m.score)
            len_err.append(m.length_cm / true_len - 1)
            in_img = kind != "swapped" and _in_images(m, t)
            kept.append((m.score, kind == "ok" and i not in hit, in_img and i not in hit_img, k,
                         w, w / t.model_weight_g - 1))
            if in_img and i not in hit_img:
                correct_img += 1
                hit_img.add(i)
            if kind == "ok":
                correct += 1 if i not in hit else 0
                hit.add(i)
                w_err.append(w / t.model_weight_g - 1)
                w_err_scatter.append(w / t.weight_g - 1)
            elif kind == "swapped":
                swapped += 1
            if kind != "ok":
                wrong_lengths.append(round(float(m.length_cm / true_len - 1), 3))
        if est_w and vis:
            survey_est += est_w
            survey_true += [t.weight_g for t in vis]
            scene_mean_err.append(np.mean(est_w) / np.mean([t.weight_g for t in vis]) - 1)
    scores, len_err = np.array(scores), np.array(len_err)
    q = np.quantile(scores, [0.25, 0.5, 0.75]) if len(scores) else []
    by_q = {}
    if len(scores):
        bins = np.digitize(scores, q)
        for b in range(4):
            sel = bins == b
            if sel.any():
                by_q[f"q{b + 1}"] = {"score_max": round(float(scores[sel].max()), 3), "n": int(sel.sum()),
                                     "median_abs_len_err_pct": round(100 * float(np.median(np.abs(len_err[sel]))), 2),
                                     "share_over_5pct": round(float(np.mean(np.abs(len_err[sel]) > 0.05)), 3)}
    med = {k: round(float(np.median(v)), 1) for k, v in stage_ms.items()}
    kept_arr = np.array(kept, dtype=float).reshape(-1, 6)
    true_mean = float(np.mean(survey_true)) if survey_true else float("nan")
    at = {}
    for cut in (0.5, 0.7, 0.9):             # the score is the chance a report is right (vision.surface_score)
        sel = kept_arr[kept_arr[:, 0] >= cut]
        n = max(len(sel), 1)
        at[f"score_ge_{cut}"] = {"reported": len(sel), "precision": round(float(sel[:, 1].sum()) / n, 3),
                                 "precision_image": round(float(sel[:, 2].sum()) / n, 3),
                                 "recall_image": round(float(sel[:, 2].sum()) / max(visible, 1), 3),
                                 "weight_mape_pct": _pct(np.mean(np.abs(sel[:, 5]))) if len(sel) else None,
                                 "survey_mean_weight_err_pct": _pct(np.mean(sel[:, 4]) / true_mean - 1)
                                 if len(sel) else None}
    return {
        "scenes": scenes, "seed": seed, "fully_visible_fish": visible, "reported": reported,
        "recall": round(correct / max(visible, 1), 3), "precision": round(correct / max(reported, 1), 3),
        "recall_strict": round(correct_strict / max(visible, 1), 3),
        "precision_strict": round(correct_strict / max(reported, 1), 3),
        "recall_image": round(correct_img / max(visible, 1), 3),
        "precision_image": round(correct_img / max(reported, 1), 3),
        "head_tail_correct": round(correct / max(correct + swapped, 1), 3),
        "tolerance": f"{TOL:.0%} of length per end across the line of sight, {TOL_DEPTH:.0%} along it, 3-D",
        "length_mape_pct_all_reported": _pct(np.mean(np.abs(len_err))) if len(len_err) else None,
        "weight_mape_pct_all_reported": _pct(np.mean(np.abs(w_err_all))) if w_err_all else None,
        "weight_mape_pct_correct": round(100 * float(np.mean(np.abs(w_err))), 2) if w_err else None,
        "weight_bias_pct": round(100 * float(np.mean(w_err)), 2) if w_err else None,
        "weight_mape_vs_scale_pct": round(100 * float(np.mean(np.abs(w_err_scatter))), 2) if w_err else None,
        "survey_mean_weight_err_pct": _pct(np.mean(survey_est) / np.mean(survey_true) - 1) if survey_est else None,
        "scene_mean_weight_abs_err_pct_median": _pct(np.median(np.abs(scene_mean_err))) if scene_mean_err else None,
        "score_vs_error": {"spearman_score_abs_len_err": round(_spearman(scores, np.abs(len_err)), 3), **by_q},
        "operating_points": at,
        "wrong_length_errors": wrong_lengths[:20],
        "ms_per_pair_median": med, "ms_per_pair_total_median": round(float(np.median(total_ms)), 1),
        "baseline_template_bank_ms_median": round(float(np.median(base_ms)), 1),
        "ratio_to_baseline": round(float(np.median(total_ms) / np.median(base_ms)), 3),
        "load": os.getloadavg()[0],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=30)
    ap.add_argument("--seed", type=int, default=1000)
    args = ap.parse_args()
    print(json.dumps(run(args.scenes, args.seed)))


if __name__ == "__main__":
    main()
