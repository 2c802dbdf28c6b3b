"""A tank's growth fitted to its weight surveys: what the rations and the production figures rest on.

One survey of n fish measures the mean weight with a standard error of CV/√n (CV ~20 %: ~4 % for
30 fish), while the fish grow ~2 % a day — so the growth between two surveys a few days apart is
mostly noise. The surveys are pooled instead: ln W is fitted linear in time (a constant specific
growth rate) by least squares, each survey weighted by 1/se² of its ln mean (se = CV/100/√n), over
the surveys of a window (controller/production.py picks it: since the last stock event that changes
which fish are in the tank, and no longer than a few weeks, since the growth rate falls as fish
grow). When the surveys scatter more than their standard errors allow (χ²/dof > 1: a survey's own
bias differs from the next's) the covariance is scaled up by that ratio and the 95 % intervals use
Student's t with the fit's degrees of freedom; otherwise the errors are known and the normal's 1.96
applies. A fit is evaluated anywhere in time, the ration's weight being its value today.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DAY_S = 86_400.0
Z95 = 1.959963984540054
MIN_SPAN_D = 1.0            # surveys closer than this measure no growth: pooled as one (two surveys a
                            # minute apart read 752 and 675 g: an SGR of -13,892 %/day, a ration of 0 g)
ASSUMED_CV_PCT = 20.0       # a survey of one fish has no CV of its own: a farmed stock's usual spread
PRIOR_Z = 3.0               # a prior further than this from the data's own fit (both errors) is left out
MIN_CV_PCT = 5.0            # a survey's CV is itself sampled: below this it would weigh too much


@dataclass(frozen=True)
class Weighing:
    """A survey as the fit sees it."""
    t: float                # farm s
    mean_weight_g: float
    cv_pct: float | None
    count: int              # fish measured

    @property
    def log_se(self) -> float:
        """Standard error of ln(mean weight): CV/√n (delta method)."""
        cv = ASSUMED_CV_PCT if self.cv_pct is None or self.count < 2 else max(self.cv_pct, MIN_CV_PCT)
        return cv / 100.0 / math.sqrt(max(self.count, 1))


@dataclass(frozen=True)
class GrowthFit:
    """ln W(t) = ln_w_ref + (sgr_pct / 100) · (t − t_ref) / day, with the covariance of
    (ln_w_ref, slope per day); ``measured`` False when the slope was not fitted (one survey) but
    taken from the chart (``prior``) — its uncertainty is then unknown."""
    t_ref: float
    ln_w_ref: float
    slope_day: float
    cov: tuple[tuple[float, float], tuple[float, float]]
    t_first: float
    t_last: float
    surveys: int
    fish: int
    scatter: float           # sqrt(χ²/dof) when above 1 (the covariance is scaled by its square), else 1
    quantile: float          # of the 95 % intervals: 1.96, or Student's t when scaled
    measured: bool

    @property
    def sgr_pct(self) -> float:
        return 100.0 * self.slope_day

    @property
    def sgr_ci_pct(self) -> float | None:
        """Half-width of the SGR's 95 % interval, % a day (None when not measured)."""
        return 100.0 * self.quantile * math.sqrt(self.cov[1][1]) if self.measured else None

    @property
    def days(self) -> float:
        return (self.t_last - self.t_first) / DAY_S

    def _row(self, t: float) -> np.ndarray:
        return np.array([1.0, (t - self.t_ref) / DAY_S])

    def ln_weight(self, t: float) -> float:
        return self.ln_w_ref + self.slope_day * (t - self.t_ref) / DAY_S

    def weight_g(self, t: float) -> float:
        return math.exp(self.ln_weight(t))

    def log_se_at(self, t: float) -> float:
        """Standard error of ln W(t); a slope taken from the chart counts as exact."""
        cov = np.array(self.cov)
        if not self.measured:
            cov[1, 1] = 0.0
        x = self._row(t)
        return float(math.sqrt(max(0.0, x @ cov @ x)))

    def weight_ci_pct(self, t: float) -> float:
        """Half-width of W(t)'s 95 % interval, % of W(t) (on the log scale: (e^{q·se} − 1)·100)."""
        return 100.0 * math.expm1(self.quantile * self.log_se_at(t))

    def grad(self, t: float) -> np.ndarray:
        """d W(t) / d (ln_w_ref, slope): for the uncertainty of sums of weights (biomass gain)."""
        return self.weight_g(t) * self._row(t)

    def summary(self, t: float | None = None) -> dict:
        """Plain data for the figures, the report and the ration."""
        out = {"model": "sgr", "sgr_pct_day": self.sgr_pct, "sgr_ci_pct_day": self.sgr_ci_pct, "surveys": self.surveys,
               "fish": self.fish, "days": self.days, "scatter": self.scatter, "measured": self.measured}
        if t is not None:
            out |= {"weight_g": self.weight_g(t), "weight_ci_pct": self.weight_ci_pct(t)}
        return out


def fit_growth(weighings: list[Weighing], prior_sgr_pct: float | None = None) -> GrowthFit | None:
    """The weighted fit of ln W on time (module docstring). None with no survey; with one, its
    mean grown at ``prior_sgr_pct`` (the chart's), or not grown when that is None too."""
    pts = sorted((w for w in weighings if w.mean_weight_g > 0 and w.count > 0), key=lambda w: w.t)
    if not pts:
        return None
    t = np.array([p.t for p in pts])
    y = np.log([p.mean_weight_g for p in pts])
    inv_var = 1.0 / np.array([p.log_se for p in pts]) ** 2
    t_ref = float(np.sum(t * inv_var) / np.sum(inv_var))          # intercept and slope uncorrelated
    x = (t - t_ref) / DAY_S
    fish = int(sum(p.count for p in pts))
    if len(pts) == 1 or np.ptp(x) < MIN_SPAN_D:
        ln_w = float(np.sum(y * inv_var) / np.sum(inv_var))
        slope = 0.0 if prior_sgr_pct is None else prior_sgr_pct / 100.0
        return GrowthFit(t_ref, ln_w, slope, ((1.0 / float(np.sum(inv_var)), 0.0), (0.0, 0.0)),
                         float(t[0]), float(t[-1]), len(pts), fish, 1.0, Z95, False)
    (ln_w, slope), cov, scale, q = _weighted_fit(np.column_stack([np.ones_like(x), x]), y, inv_var)
    return GrowthFit(t_ref, float(ln_w), float(slope), _pairs(cov), float(t[0]), float(t[-1]), len(pts), fish,
                     scale, q, True)


def _weighted_fit(X: np.ndarray, y: np.ndarray, inv_var: np.ndarray):
    """Weighted least squares of ``y`` (n,) on ``X`` (n, 2): (coefficients, covariance, scatter,
    quantile of the 95 % intervals). The covariance is scaled by χ²/dof when the points scatter
    more than their errors allow, and the intervals then use Student's t (module docstring)."""
    cov = np.linalg.inv(X.T @ (X * inv_var[:, None]))
    beta = cov @ (X.T @ (inv_var * y))
    dof = len(y) - 2
    ratio = float(np.sum(inv_var * (y - X @ beta) ** 2)) / dof if dof > 0 else 0.0
    if not ratio > 1.0:             # (NaN too)
        return beta, cov, 1.0, Z95
    from scipy import special  # here, and not scipy.stats (its t.ppf is this; ~0.45 s more to import)
    scale, q = math.sqrt(ratio), float(special.stdtrit(dof, 0.975))
    return beta, cov * scale**2, scale, q


def _pairs(cov: np.ndarray) -> tuple[tuple[float, float], tuple[float, float]]:
    return (float(cov[0, 0]), float(cov[0, 1])), (float(cov[1, 0]), float(cov[1, 1]))


@dataclass(frozen=True)
class Conversion:
    """FCR over the fit's window: feed ÷ biomass gain, the gain from the fitted weights."""
    feed_g: float
    gain_g: float
    gain_se_g: float
    quantile: float

    @property
    def fcr(self) -> float | None:
        return feed_conversion(self.feed_g, self.gain_g)

    @property
    def fcr_ci(self) -> tuple[float | None, float | None]:
        """The 95 % interval of FCR from the gain's: (feed / high gain, feed / low gain); None for
        an end the gain's interval does not bound (it reaches zero or below), or with no feed."""
        if self.feed_g <= 0:
            return None, None
        lo_gain, hi_gain = self.gain_g - self.quantile * self.gain_se_g, self.gain_g + self.quantile * self.gain_se_g
        return (self.feed_g / hi_gain if hi_gain > 0 else None, self.feed_g / lo_gain if lo_gain > 0 else None)

    def summary(self) -> dict:
        lo, hi = self.fcr_ci
        return {"fcr": self.fcr, "fcr_ci": [lo, hi], "feed_g": self.feed_g, "gain_g": self.gain_g}


def net_conversion(feed_g: float, gain_g: float, died_g: float) -> dict:
    """The net (economic) FCR beside the biological one: the feed over the biomass gained less the
    weight of the fish that died meanwhile — the growth the farm keeps. ``fcr`` (the biological)
    counts the dead fish's growth too: what the feed made, the fish's own conversion."""
    return {"fcr_net": feed_conversion(feed_g, gain_g - died_g), "died_g": died_g}


def feed_conversion(feed_g: float, gain_g: float) -> float | None:
    """Feed over gain; None with no gain (a loss is not a conversion) and with no feed recorded (the
    fish grew on feed the ledger does not know, hand-fed: it read "FCR 0.00 (0.00-0.00)")."""
    return feed_g / gain_g if gain_g > 0 and feed_g > 0 else None


def conversion(fit: GrowthFit, feed_g: float, terms: list[tuple[float, float]]) -> Conversion:
    """``terms``: (fish, t) whose fitted weight adds to the gain — +N at the window's end, −N at its
    start, +fish that left (mortality, harvests) and −fish that came, each at the time it moved."""
    gain = sum(n * fit.weight_g(t) for n, t in terms)
    grad = sum((n * fit.grad(t) for n, t in terms), np.zeros(2))
    cov = np.array(fit.cov)
    se = float(math.sqrt(max(0.0, grad @ cov @ grad))) if fit.measured else math.nan
    return Conversion(float(feed_g), float(gain), se, fit.quantile)


# -- the feed model: the fish gain what they are fed, over a conversion ratio --------------------
@dataclass(frozen=True)
class Account:
    """The ledger at ``t``, counted from the window's first survey: feed given since, the stock
    then, and the weight of the fish that left since (mortality, harvests) less that of those
    that came; of it, the weight of those that died."""
    t: float
    feed_g: float
    stock: int
    left_g: float
    died_g: float = 0.0              # the part of ``left_g`` that died (not harvested nor moved)


@dataclass(frozen=True)
class FeedFit:
    """B(t) = start_g + (feed given since the first survey) / FCR − (weight of the fish that left):
    the biomass the surveys (N·W, each weighted by 1/its se²) say the tank held at its first survey
    and the feed conversion ratio, fitted by least squares. Unlike a constant SGR it follows the
    ration: growth slows when the chart's rate steps down, and a survey a week old is brought to
    today by the feed given since. ``cov``: of (start_g, 1/FCR), scaled as GrowthFit's."""
    start_g: float
    per_feed: float                  # 1 / FCR: grams of fish a gram of feed makes
    cov: tuple[tuple[float, float], tuple[float, float]]
    first: Account
    last: Account
    surveys: int
    fish: int
    scatter: float
    quantile: float

    def biomass_g(self, a: Account) -> float:
        return self.start_g + self.per_feed * a.feed_g - a.left_g

    def weight_g(self, a: Account) -> float:
        return self.biomass_g(a) / a.stock if a.stock > 0 else math.nan

    def _log_grad(self, a: Account) -> np.ndarray:
        return np.array([1.0, a.feed_g]) / self.biomass_g(a)

    def weight_ci_pct(self, a: Account) -> float:
        g = self._log_grad(a)
        return 100.0 * math.expm1(self.quantile * math.sqrt(max(0.0, g @ np.array(self.cov) @ g)))

    @property
    def days(self) -> float:
        return (self.last.t - self.first.t) / DAY_S

    @property
    def sgr_pct(self) -> float:
        return 100.0 * math.log(self.weight_g(self.last) / self.weight_g(self.first)) / self.days

    @property
    def sgr_ci_pct(self) -> float:
        g = self._log_grad(self.last) - self._log_grad(self.first)
        return 100.0 * self.quantile * math.sqrt(max(0.0, g @ np.array(self.cov) @ g)) / self.days

    @property
    def fcr(self) -> float | None:
        return 1.0 / self.per_feed if self.per_feed > 0 else None

    @property
    def fcr_ci(self) -> tuple[float | None, float | None]:
        half = self.quantile * math.sqrt(self.cov[1][1])
        lo, hi = self.per_feed - half, self.per_feed + half
        return (1.0 / hi if hi > 0 else None, 1.0 / lo if lo > 0 else None)

    def summary(self, now: Account | None = None) -> dict:
        lo, hi = self.fcr_ci
        out = {"model": "feed", "sgr_pct_day": self.sgr_pct, "sgr_ci_pct_day": self.sgr_ci_pct,
               "surveys": self.surveys, "fish": self.fish, "days": self.days, "scatter": self.scatter,
               "measured": True, "fcr": self.fcr, "fcr_ci": [lo, hi], "feed_g": self.last.feed_g - self.first.feed_g,
               "gain_g": self.biomass_g(self.last) - self.biomass_g(self.first) + self.last.left_g - self.first.left_g}
        out |= net_conversion(out["feed_g"], out["gain_g"], self.last.died_g - self.first.died_g)
        if now is not None and now.stock > 0:
            out |= {"weight_g": self.weight_g(now), "weight_ci_pct": self.weight_ci_pct(now)}
        return out


def fit_feed(weighings: list[Weighing], accounts: list[Account],
             prior: tuple[float, float] | None = None) -> FeedFit | None:
    """The feed model's fit (FeedFit) to surveys and the ledger's accounts at their times (same
    order); None unless two surveys of a tank holding fish with feed given between them (a survey
    of a tank whose fish all left weighs nothing of its biomass). ``prior``: the conversion (gain
    per gram fed, 1/FCR) the feeding chart expects and its standard error, one more observation of
    the slope (module docstring of controller/production.py: ``CHART_PRIOR_REL``)."""
    if len(weighings) != len(accounts):
        return None
    kept = [(w, a) for w, a in zip(weighings, accounts, strict=True) if a.stock > 0 and w.mean_weight_g > 0]
    if len(kept) < 2:
        return None
    weighings, accounts = [w for w, _ in kept], [a for _, a in kept]
    feed = np.array([a.feed_g for a in accounts])
    if np.ptp(feed) <= 0:
        return None
    y = np.array([w.mean_weight_g * a.stock + a.left_g for w, a in zip(weighings, accounts, strict=True)])
    inv_var = 1.0 / np.array([w.mean_weight_g * a.stock * w.log_se
                              for w, a in zip(weighings, accounts, strict=True)]) ** 2
    X = np.column_stack([np.ones_like(feed), feed])
    beta, cov, scale, q = _weighted_fit(X, y, inv_var)
    # the chart's conversion joins the fit where the surveys and the feed could have it: a ledger
    # that misses feeds (fish fed by hand, another system) gives a conversion no chart expects, and
    # held to the chart the fit read a survey of today 11 % off its own mean
    if prior is not None and abs(beta[1] - prior[0]) <= PRIOR_Z * math.sqrt(cov[1, 1] + prior[1] ** 2):
        beta, cov, scale, q = _weighted_fit(np.vstack([X, [0.0, 1.0]]), np.append(y, prior[0]),
                                            np.append(inv_var, 1.0 / prior[1] ** 2))
    return FeedFit(float(beta[0]), float(beta[1]), _pairs(cov),
                   accounts[0], accounts[-1], len(weighings), int(sum(w.count for w in weighings)), scale, q)
