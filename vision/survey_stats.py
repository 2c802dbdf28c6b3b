"""A weight survey's result from its fish: count, mean and spread, histograms a farmer reads,
a bootstrap confidence interval on mean weight, and how many more fish would tighten it to +-2 %.

Pure: arrays in, a JSON-ready dict out (no NaN anywhere: ``None`` where a figure is undefined,
e.g. the spread of one fish). An empty survey is a valid result with count 0.
"""
from __future__ import annotations

import math

import numpy as np

LENGTH_STEPS_CM = (0.5, 1.0, 2.0, 5.0, 10.0)     # 0.5 cm classes, as a farm measuring board reads
MAX_BINS = 30                                   # wider classes rather than more than this
BOOT_CHUNK = 4_000_000                          # resampled indices held at once (memory, not speed)
# A "fish" longer than PLAUSIBLE_LONG or shorter than PLAUSIBLE_SHORT times the survey's median length
# is a measuring error (two fish taken for one, a snout on the wrong fish): one stock's fork lengths
# are one hump with a CV of ~5-15 % (weight CV up to ~45 %, ungraded), so 1.4x is 4 SDs above at 10 %
# (2.7 at 15 %: 0.4 % of such a stock's fish) and 0.55x 3 SDs below even then, while the long one's
# weight (a L^b: 2.8x the median's) adds ~35 % to the mean of a 5-fish survey. The band needs no
# spread of its own, so it holds from 3 fish (the median is then a real fish unless two of three are
# errors). Rendered grow-out surveys of 12 g fish (bench/diag_growout_survey.py, seeds 200000+) read
# +34 % and +42 % on a false pairing 1.45x and a 2.99x the median among 5-7 fish.
PLAUSIBLE_LONG = 1.4
PLAUSIBLE_SHORT = 0.55
PLAUSIBLE_MIN_FISH = 3
OUTLIER_SD = 5.0           # from more fish: robust SDs (1.4826 MAD) from the median length
OUTLIER_MIN_FISH = 10      # ... from this many fish (fewer: the MAD is itself too noisy), in place
                           # of the fixed band, which from so many fish would cut an ungraded stock's
                           # largest real fish (lengths 80-160 mm: 3 of 64 measured right left out, the
                           # mean weight -5 %); a graded one's 5 SDs lie inside the band anyway
WIDE_LONG, WIDE_SHORT = 2.0, 0.45   # ... and a band no stock spans (two fish taken for one, a fragment)


def condition_k(lengths_cm: np.ndarray, weights_g: np.ndarray) -> np.ndarray:
    """Fulton's condition factor K = 100 W / L^3 (W g, L cm) per fish."""
    lengths_cm = np.asarray(lengths_cm, dtype=float)
    return 100.0 * np.asarray(weights_g, dtype=float) / np.power(lengths_cm, 3)


def implausible(lengths_cm) -> np.ndarray:
    """(N,) bool, the lengths a survey leaves out as measuring errors: from PLAUSIBLE_MIN_FISH fish,
    those outside PLAUSIBLE_SHORT..PLAUSIBLE_LONG of the median; from OUTLIER_MIN_FISH, those
    OUTLIER_SD robust SDs from it or outside WIDE_SHORT..WIDE_LONG of it. One wild length among few
    fish is what makes a small survey read several times heavy."""
    lengths = np.asarray(lengths_cm, dtype=float).reshape(-1)
    far = np.zeros(len(lengths), bool)
    if len(lengths) < PLAUSIBLE_MIN_FISH:
        return far
    median = float(np.median(lengths))
    if median <= 0:
        return far
    if len(lengths) < OUTLIER_MIN_FISH:
        return (lengths > PLAUSIBLE_LONG * median) | (lengths < PLAUSIBLE_SHORT * median)
    far = (lengths > WIDE_LONG * median) | (lengths < WIDE_SHORT * median)
    spread = 1.4826 * float(np.median(np.abs(lengths - median)))
    if spread > 0:
        far |= np.abs(lengths - median) > OUTLIER_SD * spread
    return far


def _round_step(span: float, bins: int) -> float:
    """The smallest 1, 2, 2.5 or 5 x 10^k step that covers ``span`` in at most ``bins`` classes."""
    raw = max(span / bins, 1e-9)
    power = 10.0 ** math.floor(math.log10(raw))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        if m * power >= raw * (1 - 1e-12):
            return m * power
    return 10.0 * power


def class_edges(values: np.ndarray, step: float) -> np.ndarray:
    """Edges at multiples of ``step`` covering every value (a value on an edge opens its class)."""
    lo = math.floor(float(values.min()) / step) * step
    hi = (math.floor(float(values.max()) / step) + 1) * step
    n = int(round((hi - lo) / step))
    return np.round(lo + step * np.arange(n + 1), 10)


def length_edges(lengths_cm: np.ndarray) -> np.ndarray:
    span = float(np.ptp(lengths_cm))
    step = next((s for s in LENGTH_STEPS_CM if span / s < MAX_BINS), None) or _round_step(span, MAX_BINS)
    return class_edges(lengths_cm, step)


def weight_edges(weights_g: np.ndarray, bins: int = 20) -> np.ndarray:
    """Round-number gram classes (1, 2, 2.5, 5 x 10^k g), at most ``bins`` of them (1 g at least
    for fish over 10 g)."""
    span = float(np.ptp(weights_g))
    step = max(_round_step(span, bins), 1.0 if float(weights_g.max()) >= 10 else 0.1)
    return class_edges(weights_g, step)


def _histogram(values: np.ndarray, edges: np.ndarray) -> dict:
    if len(values) == 0:
        return {"edges": [], "counts": []}
    # np.histogram closes the last class on the right; class_edges leaves room above the max anyway
    counts, _ = np.histogram(values, bins=edges)
    return {"edges": [float(e) for e in edges], "counts": [int(c) for c in counts]}


def bootstrap_means(values: np.ndarray, rng: np.random.Generator, n_boot: int = 2000) -> np.ndarray:
    """Means of ``n_boot`` resamples with replacement; vectorised in chunks of bounded memory."""
    n = len(values)
    out = np.empty(n_boot)
    per = max(1, BOOT_CHUNK // max(n, 1))
    for start in range(0, n_boot, per):
        k = min(per, n_boot - start)
        out[start:start + k] = values[rng.integers(0, n, size=(k, n))].mean(axis=1)
    return out


def small_sample_factor(n: int, level: float = 0.95) -> float:
    """How much wider than the percentile bootstrap's a mean's interval from ``n`` values must be:
    the bootstrap's spread of means is the plug-in sd/sqrt(n) (divisor n, not n - 1), and it takes
    the normal's quantile where the mean of a few has Student's t with n - 1 degrees of freedom:
    sqrt(n / (n - 1)) t / z (2 fish: 9.2, 3: 2.7, 5: 1.58, 10: 1.22, 30: 1.06, 100: 1.02). Left out,
    a "95 %" interval from 2 fish was their two weights and held the stock's mean ~half the time,
    from 5 fish 83 % (an outside tester's coverage runs, lognormal weights)."""
    from scipy import special  # stats.t.ppf and stats.norm.ppf's own functions: scipy.stats takes ~0.45 s
    z = special.ndtri((1 + level) / 2)
    return float(math.sqrt(n / (n - 1)) * special.stdtrit(n - 1, (1 + level) / 2) / z)


def _num(x) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _spread(values: np.ndarray) -> dict:
    n = len(values)
    mean = float(values.mean()) if n else None
    std = float(values.std(ddof=1)) if n >= 2 else None
    cv = std / mean if std is not None and mean else None
    return {"mean": _num(mean), "std": _num(std), "cv": _num(cv)}


def summarise(lengths_cm, weights_g, *, rng: np.random.Generator, n_boot: int = 2000, level: float = 0.95,
              target: float = 0.02, length_bins: np.ndarray | None = None,
              weight_bins: np.ndarray | None = None) -> dict:
    """The survey's statistics, one entry per fish (stills) or per track (video).

    ``weight_g.ci`` is the percentile bootstrap interval of the mean weight at ``level``, widened
    about the mean by ``small_sample_factor`` (never below 0 g);
    ``precision`` says how many fish in all (and how many more) would bring its half-width to
    ``target`` of the mean, scaling the bootstrap's half-width (not widened) as 1/sqrt(n).
    Undefined figures are None.
    """
    lengths = np.asarray(lengths_cm, dtype=float).reshape(-1)
    weights = np.asarray(weights_g, dtype=float).reshape(-1)
    if lengths.shape != weights.shape:
        raise ValueError(f"{len(lengths)} lengths but {len(weights)} weights")
    if not (np.all(np.isfinite(lengths)) and np.all(np.isfinite(weights))):
        raise ValueError("lengths and weights must be finite")
    n = len(lengths)
    length = _spread(lengths)
    weight = _spread(weights)
    length["histogram"] = _histogram(lengths, length_bins if length_bins is not None
                                     else (length_edges(lengths) if n else None))
    weight["histogram"] = _histogram(weights, weight_bins if weight_bins is not None
                                     else (weight_edges(weights) if n else None))
    ci = None
    precision = {"target_pct": 100 * target, "half_width_pct": None, "fish_needed": None, "more_fish": None}
    if n >= 2:
        means = bootstrap_means(weights, rng, n_boot)
        lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
        mean = weight["mean"]
        # what the bootstrap's half-width becomes with many fish (the plug-in's n - 1): the interval's
        # small-sample widening fades as fish are added, so it does not scale with them (from 2 fish
        # it would have asked for 85 x as many)
        settled = (hi - lo) / 2 * math.sqrt(n / (n - 1))
        f = small_sample_factor(n, level)
        lo, hi = max(0.0, mean - f * (mean - lo)), mean + f * (hi - mean)
        ci = [float(lo), float(hi)]
        half = (hi - lo) / 2
        if mean:
            precision["half_width_pct"] = _num(100 * half / mean)
            needed = n if half <= target * mean else max(n + 1, math.ceil(n * (settled / (target * mean)) ** 2))
            precision.update(fish_needed=int(needed), more_fish=int(needed - n))
    weight["ci"] = ci
    weight["ci_level"] = level
    k = condition_k(lengths, weights) if n else np.empty(0)
    cond = _spread(k)
    cond.pop("cv")
    return {"count": n, "length_cm": length, "weight_g": weight, "condition_k": cond,
            "precision": precision}
