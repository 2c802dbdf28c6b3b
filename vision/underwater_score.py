"""The survey's last stage for one pair: the quality score of every associated fish (the product of
terms, each 1 when that part of the measurement is as good as it gets; ``vision.underwater``'s
docstring; or, with ``Params.learned_score``, the fitted chance that the report is right,
``vision.learned_score``), the post-filters, and one fish per snout."""
from __future__ import annotations

import numpy as np

from vision import learned_score
from vision.silhouettes import body_fill
from vision.survey_types import FishMeasurement


def measurements(rows, pairs, f1, f2, v1, v2, fork_mm, fork_res, ch, calib, geo, p,
                  width: int, expected: np.ndarray, view: np.ndarray, epipolar: tuple[np.ndarray, ...],
                  keypoint_conf: np.ndarray,
                  keypoint_snout: np.ndarray, snout_net_conf: np.ndarray) -> list[FishMeasurement]:
    if len(rows) == 0:
        return []
    fork_epi, snout_epi, fork_best, snout_best = epipolar
    c1 = -np.linalg.solve(calib.P1[:, :3], calib.P1[:, 3])
    rng_mm = np.linalg.norm(fork_mm - c1, axis=1)
    len_px = 0.5 * (np.linalg.norm(ch.px1 - f1.xy, axis=1) + np.linalg.norm(ch.px2 - f2.xy, axis=1))
    fill = np.minimum(body_fill(v1.comps, *v1.scale, f1.xy, ch.px1), body_fill(v2.comps, *v2.scale, f2.xy, ch.px2)) \
        if p.outlines else np.ones(len(f1))
    net_sure = np.minimum(v1.sure()[pairs.i], v2.sure()[pairs.j])     # the fork locator's, the worse view
    terms = {
        "t_fill": np.clip((fill - p.min_fill) / (1 - p.min_fill), 0, 1) if p.min_fill < 1 else np.ones(len(f1)),
        "t_stereo": np.clip((pairs.ncc - 0.4) / 0.5, 0, 1),
        # eq. (13)'s bank is drawn with a forked tail: a square-cut or worn tail the locator found
        # scores low on it without being any less a tail, so the bank lowers the score, never vetoes
        "t_fin": p.fin_floor + (1 - p.fin_floor) * np.clip((np.minimum(f1.score, f2.score) - 0.3) / 0.4, 0, 1),
        "t_fork_residual": np.exp(-(fork_res / 1.5) ** 2),
        "t_snout_residual": np.exp(-(ch.residual_px / 1.5) ** 2),
        "t_snout_edge": np.clip(ch.strength, 0, 1),
        "t_tilt": np.clip(1 - (ch.tilt_deg / geo.max_tilt_deg) ** 2, 0, 1),
        "t_size": np.clip(len_px / (p.good_length_px * width / 1280.0), 0, 1),
        "t_fork_shape": np.exp(-(np.maximum(v1.arm_rms[pairs.i], v2.arm_rms[pairs.j]) / 0.03) ** 2),
        "t_fork_net": net_sure ** p.net_weight,
        # the length against the body's region it was found from: a snout taken past the real one
        # (into a fish ahead) or short of it (a shade across the head) disagrees
        # (whether the faint fin is part of that region or not moves it by ~20 %: no penalty there)
        "t_snout_view": view,
        # the keypoint net's confidence in both forks (``Params.kp_floor``: 1 leaves the score alone)
        "t_keypoints": p.kp_floor + (1 - p.kp_floor) * keypoint_conf,
        "t_keypoint_snout": p.kp_snout_floor + (1 - p.kp_snout_floor) * keypoint_snout,
        "t_body": np.exp(-(np.maximum(np.abs(np.log(np.maximum(ch.length_mm, 1e-6) / expected)) - 0.2, 0) / 0.15) ** 2),
    }
    score = np.prod(np.stack(list(terms.values())), axis=0)
    raw = {"stereo_ncc": pairs.ncc, "fork_residual_px": fork_res, "snout_residual_px": ch.residual_px,
           "tilt_deg": ch.tilt_deg, "range_mm": rng_mm, "length_px": len_px,
           "fin_ncc": np.minimum(f1.score, f2.score), "snout_edge": ch.strength, "body_length_mm": expected,
           "body_fill": fill, "fork_epi_px": fork_epi, "snout_epi_px": snout_epi,
           "fork_epi_best_px": fork_best, "snout_epi_best_px": snout_best,
           "fork_net_conf": net_sure, "kp_fork_conf": keypoint_conf,
           "kp_snout_agree": keypoint_snout, "snout_net_conf": snout_net_conf}
    raw["hand_score"] = score
    min_score = p.min_score
    if p.learned_score:
        score = learned_score.chance(raw | terms | {"length_mm": ch.length_mm})
        min_score = p.min_chance
    fish = []
    # post-filter: an end the other image's best match along its epipolar line puts elsewhere
    # is on the wrong structure there, and its depth with it. From either view: a wrong end is
    # elsewhere from both, while a right one lying along the line (a fish swimming along the
    # baseline) can be matched a little along its own body from one view
    epi = np.maximum(*((fork_best, snout_best) if p.epipolar_either else (fork_epi, snout_epi)))
    epi = epi / np.maximum(len_px, 1e-6)
    rows = rows[(score[rows] >= min_score) & (epi[rows] <= p.max_epipolar)
                & (fork_res[rows] <= p.max_fork_residual_px)]
    for r in _unique_snouts(rows, ch, score):
        q = {k: float(v[r]) for k, v in raw.items()} | {k: float(v[r]) for k, v in terms.items()}
        fish.append(FishMeasurement(snout_mm=ch.mm[r].copy(), fork_mm=fork_mm[r].copy(),
                                    snout_px=np.array([ch.px1[r], ch.px2[r]]),
                                    fork_px=np.array([f1.xy[r], f2.xy[r]]), score=float(score[r]), quality=q))
    return fish


def _unique_snouts(rows: np.ndarray, ch, score: np.ndarray) -> list[int]:
    """Two forks claiming one snout (within 3 % of the length): the better-scored keeps it."""
    rows = rows[np.argsort(-score[rows], kind="stable")]
    taken: list[int] = []
    for r in rows:                                   # a few dozen fish at most
        if all(np.linalg.norm(ch.mm[r] - ch.mm[t]) > 0.03 * ch.length_mm[r] for t in taken):
            taken.append(int(r))
    return taken
