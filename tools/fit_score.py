"""Fit ``vision.learned_score``'s logistic model on reports from tools/score_data.py and write it
as a Python module (``vision/models/fish_score.py``: vision reads no files); with ``--setup surface``
``vision.surface_score``'s, on reports from tools/surface_score_data.py
(``vision/models/surface_score.py``).

Run: ``.venv/bin/python tools/fit_score.py --data /tmp/score_a.npz /tmp/score_b.npz
--val /tmp/score_c.npz --out vision/models/fish_score.py`` (seconds; scipy's L-BFGS on the
L2-penalised log loss of standardised features). Prints, on the ``--val`` reports, the share of
fully visible fish found at precision 0.95 and 0.97 when reports are kept from the best down, by
the hand-made score and by the fitted chance (JSON).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from vision import learned_score, surface_score  # noqa: E402


def load(paths: list[str]) -> tuple[dict[str, np.ndarray], int]:
    """The reports' columns (by name) and the fully visible fish, over the files."""
    cols: dict[str, list[np.ndarray]] = {}
    visible = 0
    for path in paths:
        d = np.load(path)
        for i, k in enumerate(map(str, d["keys"])):
            cols.setdefault(k, []).append(d["rows"][:, i])
        visible += int(d["fully_visible"])
    q = {k: np.concatenate(v) for k, v in cols.items()}
    q["length_mm"] = 10.0 * q["length_cm"]
    return q, visible


def fit(x: np.ndarray, y: np.ndarray, l2: float) -> tuple[np.ndarray, float]:
    def loss(theta):
        w, b = theta[:-1], theta[-1]
        z = x @ w + b
        p = 1.0 / (1.0 + np.exp(-z))
        value = np.mean(np.logaddexp(0.0, z) - y * z) + l2 * w @ w
        g = (p - y) / len(y)
        return value, np.r_[x.T @ g + 2 * l2 * w, g.sum()]
    res = minimize(loss, np.zeros(x.shape[1] + 1), jac=True, method="L-BFGS-B")
    return res.x[:-1], float(res.x[-1])


def recall_at(s: np.ndarray, right: np.ndarray, found: np.ndarray, visible: int, precision: float) -> dict:
    order = np.argsort(-s, kind="stable")
    prec = np.cumsum(right[order]) / np.arange(1, len(s) + 1)
    ok = np.flatnonzero(prec >= precision)
    if len(ok) == 0:
        return {"recall": 0.0, "threshold": None}
    k = ok.max()
    return {"recall": round(float(np.cumsum(found[order])[k] / max(visible, 1)), 3),
            "threshold": round(float(s[order][k]), 4)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--val", nargs="*", default=[])
    ap.add_argument("--out")
    ap.add_argument("--l2", type=float, default=1e-3)
    ap.add_argument("--setup", choices=["underwater", "surface"], default="underwater",
                    help="whose model: vision.learned_score's or vision.surface_score's features")
    ap.add_argument("--features", help="comma-separated names of the setup's FEATURES (default: all)")
    ap.add_argument("--precisions", type=lambda v: [float(x) for x in v.split(",")], default=[0.95, 0.97],
                    help="the recall and threshold printed at each of these precisions on --val")
    args = ap.parse_args()
    scoring = surface_score if args.setup == "surface" else learned_score
    names = args.features.split(",") if args.features else list(scoring.FEATURES)
    q, _ = load(args.data)
    x = learned_score.features(q, names, scoring.FEATURES)
    mean, sd = x.mean(axis=0), x.std(axis=0) + 1e-9
    w, b = fit((x - mean) / sd, q["right"], args.l2)
    model = {"names": names, "mean": mean.tolist(), "sd": sd.tolist(), "weights": w.tolist(), "bias": b,
             "fitted_on": f"rendered {args.setup} scenes, seeds {int(q['seed'].min())}-{int(q['seed'].max())}",
             "reports": int(len(x)), "right": int(q["right"].sum()), "l2": args.l2}
    report = {"reports": len(x), "right": int(q["right"].sum()),
              "weights": {n: round(float(v), 3) for n, v in zip(names, w, strict=True)}}
    if args.val:
        v, visible = load(args.val)
        right, found = v["right"] == 1, (v["right"] == 1) & (v["visible"] == 1)
        for name, s in (("hand_made", v["score"]), ("learned", scoring.chance(v, model))):
            report[name] = {str(p): recall_at(s, right, found, visible, p) for p in args.precisions}
        report["val_upper_bound_recall"] = round(float(found.sum() / max(visible, 1)), 3)
    if args.out:
        Path(args.out).write_text(f'"""{scoring.__name__}\'s fitted model, written by tools/fit_score.py '
                                  '(do not edit by hand)."""\n\nMODEL = ' + json.dumps(model, indent=1) + "\n")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
