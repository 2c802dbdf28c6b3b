"""Production figures a manager reads, per tank, between consecutive weight surveys.

For surveys 1 and 2 of a tank (mean weights W1, W2 g; stocks N1, N2 at their times, from the
config's count and the stock events; ``days`` apart):

- specific growth rate  SGR = 100 · (ln W2 − ln W1) / days          (% a day)
- biomass gain          G = N2·W2 − N1·W1 + Σ fish out · W(t) − Σ fish in · W'(t)
  (mortality, harvests and transfers between the surveys, each weighed at the weight the tank's
  fish had then, W(t) growing exponentially from W1 to W2): the growth the feed made, whether the
  fish are still in the tank or not. Fish moved in are weighed as their source tank's surveys had
  them (``moved_in_weights``: W'(t)), not as this tank's: 100 fish of 200 g moved among fish of
  20 g would otherwise count 18 kg they brought as grown here;
- feed conversion ratio FCR = feed given / G   (the grams of the feed rows done between them; none
  when G ≤ 0: a loss is not a conversion) — the biological ratio, the fish's own conversion; beside
  it the net (economic) ratio ``fcr_net`` = feed given / (G − Σ fish that died · W(t)): the growth
  the farm keeps, the dead fish's left out;
- condition factor      K = 100 · W / L³ per fish (g, cm), the survey's mean;
- size uniformity       CV = sd / mean of weight (%), and whether it calls for grading;
- projection: the days to a target weight at the fitted SGR (below; the last interval's without
  a fit), from the fitted weight at the newest survey, and the date.

Beside them, the same figures from the tank's growth fitted to every survey of a window
(controller/growth.py): SGR with its 95 % interval, and FCR = feed ÷ the gain between the fitted
weights at the window's first and last survey (the same moves of fish counted), with its interval,
and the fitted weight across the window with its 95 % interval (``curve``: [t, g, ± %] rows).
The window: the surveys since the last harvest or transfer of the tank (they change which fish are
in it: a fit across one mixes two stocks) and within ``[feeding] growth_window_d`` of the newest.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.growth import (
    Account,
    FeedFit,
    GrowthFit,
    Weighing,
    conversion,
    feed_conversion,
    fit_feed,
    fit_growth,
    net_conversion,
)
from devices.clock import farm_date

DAY_S = 86_400.0


@dataclass(frozen=True)
class SurveyPoint:
    t: float
    mean_weight_g: float
    cv_pct: float
    k: float                   # mean condition factor of its fish
    count: int                 # fish measured
    stock: int                 # fish in the tank then


@dataclass(frozen=True)
class Interval:
    t1: float
    t2: float
    days: float
    sgr_pct: float
    feed_g: float
    gain_g: float
    fcr: float | None
    fcr_net: float | None = None       # the feed over the gain less the dead fish's weight
    died_g: float = 0.0


def condition_factor(lengths_cm, weights_g) -> float:
    """Mean of 100 · W / L³ over the fish."""
    length, weight = np.asarray(lengths_cm, float), np.asarray(weights_g, float)
    return float(np.mean(100.0 * weight / length**3)) if length.size else math.nan


def fish_out(event, tank: str) -> int:
    """The fish a stock event (t, tank, count, to_tank: out of ``tank``, into ``to_tank``) takes out
    of ``tank``, less those it brings in."""
    return (event["count"] if event["tank"] == tank else 0) - (event["count"] if event["to_tank"] == tank else 0)


def stock_at(base: int, events, tank: str, t: float) -> int:
    """The tank's fish at farm time ``t``: ``base`` (the config's count) less the stock events' up to ``t``."""
    return base - sum(fish_out(e, tank) for e in events if e["t"] <= t)


def emptied_at(base: int, events, tank: str, t: float) -> float | None:
    """The last farm time up to ``t`` the tank's stock events took all its fish: its surveys before
    then describe fish that are gone (a full harvest, then fish moved in, were fed as the harvested
    ones). None when it has held fish throughout."""
    stock, last = base, None
    for e in sorted((e for e in events if e["t"] <= t), key=lambda e: e["t"]):
        stock -= fish_out(e, tank)
        if stock <= 0 and fish_out(e, tank) > 0:
            last = e["t"]
    return last


def weight_at(t: float, p1: SurveyPoint, p2: SurveyPoint) -> float:
    """Exponential growth from one survey's mean weight to the next's."""
    f = min(1.0, max(0.0, (t - p1.t) / (p2.t - p1.t)))
    return p1.mean_weight_g * (p2.mean_weight_g / p1.mean_weight_g) ** f


def interval(p1: SurveyPoint, p2: SurveyPoint, feed_g: float, events, tank: str,
             brought: dict | None = None) -> Interval:
    """The figures between two surveys of ``tank`` (module docstring); ``feed_g``: feed given
    between them; ``events``: the stock events (all of them: those between count); ``brought``:
    event id -> mean weight (g) of the fish a transfer into ``tank`` brought, where known
    (``moved_in_weights``; else they are weighed as the tank's own fish)."""
    days = (p2.t - p1.t) / DAY_S
    if days <= 0:
        raise ValueError("the second survey must come after the first")
    sgr = 100.0 * (math.log(p2.mean_weight_g) - math.log(p1.mean_weight_g)) / days
    brought = brought or {}

    def weight(e) -> float:
        if e["to_tank"] == tank and e["tank"] != tank and e.get("id") in brought:
            return brought[e["id"]]
        return weight_at(e["t"], p1, p2)
    moved = [(e["kind"], fish_out(e, tank) * weight(e)) for e in events if p1.t < e["t"] <= p2.t]
    gain = p2.stock * p2.mean_weight_g - p1.stock * p1.mean_weight_g + sum(g for _, g in moved)
    died = sum(g for kind, g in moved if kind == "mortality")
    net = net_conversion(feed_g, gain, died)
    return Interval(p1.t, p2.t, days, sgr, feed_g, gain, feed_conversion(feed_g, gain), net["fcr_net"], died)


def moved_in_weights(cfg, store, events, tank: str) -> dict[int, float]:
    """Event id -> mean weight (g) of the fish each transfer into ``tank`` brought, from the
    source tank's surveys that counted fish: grown between the newest before the transfer and the
    next after it (exponentially, as ``weight_at``) when the source kept fish through both, else
    the newest before as it stands. A source never surveyed before the transfer is left out."""
    out = {}
    bases = {t.id: t.stock for t in cfg.tanks}
    for e in events:
        if e["kind"] != "transfer" or e["to_tank"] != tank or e["tank"] == tank:
            continue
        before = store.surveys(e["tank"], until=e["t"], limit=1)
        if not before:
            continue
        s1 = before[0]
        s2 = min(store.surveys(e["tank"], since=e["t"] + 1e-6), key=lambda s: s.t, default=None)
        base = bases.get(e["tank"])
        # the source's next survey is of the same fish only if it was not emptied before it
        same = s2 is not None and base is not None and (emptied_at(base, events, e["tank"], s2.t) or -math.inf) < s1.t
        out[e["id"]] = weight_at(e["t"], _point(s1), _point(s2)) if same else s1.mean_weight_g
    return out


def _point(s) -> SurveyPoint:
    return SurveyPoint(s.t, s.mean_weight_g, s.cv_pct or 0.0, math.nan, s.count, 0)


CURVE_POINTS = 60                       # the fitted growth drawn across its window (report's "curve")
BREAKS = ("harvest", "transfer")        # stock events after which the fit starts again


def growth_window(store, tank_id: str, t: float, window_d: float, base: int | None = None) -> list:
    """The surveys the growth fit pools at ``t``, oldest first (module docstring); with ``base``
    (the config's stock) none from before the tank last held no fish."""
    rows = store.surveys(tank_id, until=t)
    if not rows:
        return []
    events = [dict(e) for e in store.stock_events()]
    emptied = None if base is None else emptied_at(base, events, tank_id, t)
    rows = [r for r in rows if emptied is None or r.t > emptied]      # of fish that are gone: none
    if not rows:
        return []
    moved = [e["t"] for e in events
             if e["kind"] in BREAKS and e["t"] <= t and tank_id in (e["tank"], e["to_tank"])]
    start = max([rows[0].t - window_d * DAY_S, *moved])
    return sorted((r for r in rows if r.t >= start), key=lambda r: r.t) or [rows[0]]


def tank_growth(store, tank_id: str, t: float, window_d: float,
                prior_sgr_pct: float | None = None, base: int | None = None) -> tuple[GrowthFit, list] | None:
    """The tank's growth fit at ``t`` and the surveys it rests on; None before any survey (of the
    fish in it now, with ``base``: growth_window)."""
    rows = growth_window(store, tank_id, t, window_d, base)
    fit = fit_growth([Weighing(r.t, r.mean_weight_g, r.cv_pct, r.count) for r in rows], prior_sgr_pct)
    return None if fit is None else (fit, rows)


# standard errors a survey may lie off the growth so far before it is flagged: 4 (the normal's two-sided
# 6e-5), not 3.29 (0.1 %): a constant SGR extrapolated a week overshoots fish whose growth slows, and at
# 3.29 one honest survey of 56 was flagged in each of two 60-day grow-outs (-13.0 % against 12.0 %,
# -12.0 % against 10.1 %; both sampling lows after surveys that read high); at 4 neither is
OFF_GROWTH_Z = 4.0


def against_growth(store, tank_id: str, survey, window_d: float) -> dict | None:
    """How ``survey`` (a ledger row) reads against the growth fitted to the tank's surveys before it
    (the same window as the rations'): ``off_pct`` its mean weight above (+) or below (−) the fitted
    weight at its time, ``band_pct`` the half-width beyond which that is flagged (``off``): the two
    uncertainties together (the fit's at that time, scaled up where the surveys scatter beyond their
    errors, and the survey's CV/√n) times ``OFF_GROWTH_Z``. The normal's quantile, not Student's t:
    with two to four surveys before, t's 0.1 % would flag nothing short of a factor of ten. A fish's
    weight does not jump within a week; a camera knocked out of its calibration does. None without a
    measured growth before it (fewer than two surveys)."""
    rows = [r for r in growth_window(store, tank_id, survey.t, window_d) if r.id != survey.id]
    fit = fit_growth([Weighing(r.t, r.mean_weight_g, r.cv_pct, r.count) for r in rows])
    if fit is None or not fit.measured or not survey.mean_weight_g:
        return None
    own = Weighing(survey.t, survey.mean_weight_g, survey.cv_pct, survey.count).log_se
    d = math.log(survey.mean_weight_g) - fit.ln_weight(survey.t)
    band = OFF_GROWTH_Z * math.hypot(fit.log_se_at(survey.t), own)
    # the band on the side the survey lies (on the log scale, so the two sides differ in %)
    return {"off_pct": 100.0 * math.expm1(d), "band_pct": 100.0 * math.expm1(math.copysign(band, d)),
            "off": bool(abs(d) > band), "surveys": fit.surveys, "fitted_g": fit.weight_g(survey.t)}


def _accounts(cfg, store, tank_id: str, t_first: float, times: list[float], weight_at) -> list[Account]:
    """The ledger at each of ``times`` since ``t_first`` (growth.Account); the fish that moved are
    weighed at ``weight_at(t)``."""
    base, events = cfg.tank(tank_id).stock, [dict(e) for e in store.stock_events()]
    out = []
    for t in times:
        moved = [(e, fish_out(e, tank_id) * weight_at(e["t"])) for e in events if t_first < e["t"] <= t]
        out.append(Account(t, store.fed_between(tank_id, t_first, t), stock_at(base, events, tank_id, t),
                           sum(g for _, g in moved), sum(g for e, g in moved if e["kind"] == "mortality")))
    return out


# For a ration (``fitted_weight`` with the tank's chart), the feed model's conversion (gain per gram
# fed) is fitted with the feeding chart's expectation (its class's SGR over its rate, at the fish's
# mean weight in the window) as one more observation, standard error this share of it. Two surveys a
# week apart, each off by its water's bias and its sampling (~3-5 %), fix a conversion to within
# ~50 %, and a week's projection on it took rations 10-17 % over the fish's biomass; the chart's is
# a farm's expectation before it has data, and a month of surveys outweighs it. The figures a
# manager reads (``fitted_figures``, the report) stay the surveys' and the feed's alone.
# Replayed on five 60-day grow-out ledgers (bench_growout: the same surveys and feeds), rations
# within 5 % of the true biomass: 2,160 -> 2,253 of 2,420 (the chart's FCR 1.21-1.36 there, the
# fish's 1.40); at 0.1, more (the prior nearly all there is early) but a chart 29 % optimistic
# (FCR 1.0) would have cost 279 of the 2,160 where at 0.25 it costs 22.
CHART_PRIOR_REL = 0.25


def chart_conversion(chart, weight_g: float) -> float | None:
    """The feeding chart's expected conversion for fish of ``weight_g``: the SGR over the rate of
    their class (both % of body weight a day), ``chart`` = (FeedingTable, water °C); None where the
    chart has no SGR."""
    table, temp = chart
    sgr, rate = table.sgr_pct(weight_g, temp), float(table.rate_pct(weight_g, temp))
    return sgr / rate if sgr is not None and sgr > 0 and rate > 0 else None


def _feed_fit(cfg, store, tank_id: str, fit: GrowthFit, rows, chart=None) -> FeedFit | None:
    """The feed model's fit, or None where it cannot stand (module docstring of controller/growth.py):
    no feed between the surveys, or a fitted biomass that is not positive (data it does not fit)."""
    times = [r.t for r in rows]
    k = None if chart is None else chart_conversion(chart, float(np.mean([r.mean_weight_g for r in rows])))
    feed = fit_feed([Weighing(r.t, r.mean_weight_g, r.cv_pct, r.count) for r in rows],
                    _accounts(cfg, store, tank_id, times[0], times, fit.weight_g),
                    prior=None if k is None else (k, CHART_PRIOR_REL * k))
    if feed is None or min(feed.biomass_g(feed.first), feed.biomass_g(feed.last)) <= 0:
        return None
    return feed


def fitted_weight(cfg, store, tank_id: str, t: float, chart=None) -> tuple[float, dict, str] | None | str:
    """The tank's mean weight at ``t`` from its growth fit (``[feeding] growth_model``), the fit's
    summary and how it was had; None without a measured growth (fewer than two surveys a day or
    more apart); a string saying why, for a fit that measures the fish losing weight while fed (a
    survey that read wrong: extrapolated, it shrank a tank's ration towards nothing)."""
    got = tank_growth(store, tank_id, t, cfg.feeding.growth_window_d, base=cfg.tank(tank_id).stock)
    if got is None or not got[0].measured:
        return None
    fit, rows = got
    if cfg.feeding.growth_model == "feed":
        feed = _feed_fit(cfg, store, tank_id, fit, rows, chart)
        if feed is not None:
            if feed.fcr is None:
                return f"the surveys' growth not used: fish fed {feed.summary()['feed_g'] / 1000:.1f} kg read lighter"
            [now] = _accounts(cfg, store, tank_id, feed.first.t, [t], fit.weight_g)
            if now.stock > 0 and feed.biomass_g(now) > 0:
                return (feed.weight_g(now), feed.summary(now),
                        f"{feed.fcr:.2f} FCR fitted to {feed.surveys} surveys and the feed since")
    if fit.sgr_pct <= 0 and store.fed_between(tank_id, fit.t_first, fit.t_last) > 0:
        return f"the surveys' growth not used: {fit.sgr_pct:.2f} %/day while fed"
    return fit.weight_g(t), fit.summary(t), f"{fit.sgr_pct:.2f} %/day fitted to {fit.surveys} surveys"


def fitted_figures(cfg, store, tank_id: str, t: float) -> dict | None:
    """SGR and FCR over the fit's window, with their 95 % intervals (module docstring)."""
    got = tank_growth(store, tank_id, t, cfg.feeding.growth_window_d, base=cfg.tank(tank_id).stock)
    if got is None or not got[0].measured:
        return None
    fit, rows = got
    t1, t2 = fit.t_first, fit.t_last
    when = {"since": farm_date(t1, cfg.utc_offset_h), "t_first": t1, "t_last": t2}
    times = [float(t) for t in np.linspace(t1, t2, CURVE_POINTS)]
    if cfg.feeding.growth_model == "feed":
        feed = _feed_fit(cfg, store, tank_id, fit, rows)
        if feed is not None:
            accounts = _accounts(cfg, store, tank_id, feed.first.t, times, fit.weight_g)
            curve = [[a.t, feed.weight_g(a), feed.weight_ci_pct(a)] for a in accounts]
            return {**feed.summary(feed.last), **when, "curve": curve}
    when["curve"] = [[t, fit.weight_g(t), fit.weight_ci_pct(t)] for t in times]
    base, events = cfg.tank(tank_id).stock, [dict(e) for e in store.stock_events()]
    terms = [(stock_at(base, events, tank_id, t2), t2), (-stock_at(base, events, tank_id, t1), t1)]
    terms += [(fish_out(e, tank_id), e["t"]) for e in events if t1 < e["t"] <= t2]
    conv = conversion(fit, store.fed_between(tank_id, t1, t2), terms)
    died = sum(fish_out(e, tank_id) * fit.weight_g(e["t"]) for e in events
               if t1 < e["t"] <= t2 and e["kind"] == "mortality")
    return {**fit.summary(t2), **conv.summary(), **net_conversion(conv.feed_g, conv.gain_g, died), **when}


def days_to(target_g: float, weight_g: float, sgr_pct: float) -> float | None:
    """Days from ``weight_g`` to ``target_g`` at ``sgr_pct``; 0 when there already, None when the
    fish are not growing."""
    if weight_g >= target_g:
        return 0.0
    if sgr_pct <= 0:
        return None
    return 100.0 * math.log(target_g / weight_g) / sgr_pct


def needs_grading(cv_pct: float, limit_pct: float) -> bool:
    return bool(cv_pct > limit_pct)


def tank_figures(cfg, store, tank_id: str, since: float | None = None, target_g: float | None = None,
                 *, last: int | None = None) -> dict:
    """A tank's figures from the ledger as plain data (``fishfarm report --json``): its surveys
    since ``since`` (the newest ``last`` of them), the intervals between, uniformity, projection."""
    tank = cfg.tank(tank_id)
    events = [dict(e) for e in store.stock_events()]
    rows = sorted(store.surveys(tank_id, since=since, limit=last), key=lambda s: s.t)
    points, surveys = [], []
    for s in rows:
        lengths, weights = store.survey_fish(s.id)
        p = SurveyPoint(s.t, s.mean_weight_g, s.cv_pct or 0.0, condition_factor(lengths, weights), s.count,
                        stock_at(tank.stock, events, tank_id, s.t))
        points.append(p)
        surveys.append({"t": s.t, "date": farm_date(s.t, cfg.utc_offset_h), "fish": s.count,
                        "mean_weight_g": s.mean_weight_g, "cv_pct": s.cv_pct, "k": p.k, "stock": p.stock,
                        "weights_g": [float(w) for w in weights]})
    brought = moved_in_weights(cfg, store, events, tank_id)
    intervals = [{**interval(a, b, store.fed_between(tank_id, a.t, b.t), events, tank_id, brought).__dict__,
                  "date1": farm_date(a.t, cfg.utc_offset_h), "date2": farm_date(b.t, cfg.utc_offset_h)}
                 for a, b in zip(points, points[1:], strict=False)]
    # surveys that counted too few fish to weigh the tank (none, or fewer than [surveys]
    # min_weighed_fish): none of the figures rests on them, but a manager wants to know
    empty = [{"t": e.t, "date": farm_date(e.t, cfg.utc_offset_h), "source": e.source, "fish": e.count}
             for e in sorted(store.surveys(tank_id, since=since, counted=False), key=lambda s: s.t)]
    out = {"tank": tank_id, "species": tank.species, "utc_offset_h": cfg.utc_offset_h, "surveys": surveys,
           "intervals": intervals, "empty_surveys": empty,
           "grading_cv_pct": cfg.feeding.grading_cv_pct, "feed_per_day": store.feed_per_day(tank_id, since)}
    if since is not None:
        out["since"] = farm_date(since, cfg.utc_offset_h)
        out["surveys_before"] = len(store.surveys(tank_id, until=since))
    if points:
        newest = points[-1]
        out["grading"] = needs_grading(newest.cv_pct, cfg.feeding.grading_cv_pct)
        fit = out["fit"] = fitted_figures(cfg, store, tank_id, newest.t)
        target = target_g if target_g is not None else tank.target_weight_g
        if target is not None and intervals:       # from the fitted growth: pooled, it is the steadier
            sgr, weight = ((fit["sgr_pct_day"], fit["weight_g"]) if fit is not None
                           else (intervals[-1]["sgr_pct"], newest.mean_weight_g))
            days = days_to(target, weight, sgr)
            out["projection"] = {"target_g": target, "sgr_pct": sgr, "days": days, "weight_g": weight,
                                 "date": None if days is None else farm_date(newest.t + days * DAY_S,
                                                                           cfg.utc_offset_h),
                                 "basis": "fit" if fit is not None else "last interval",
                                 "reached": weight >= target}
    return out
