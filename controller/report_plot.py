"""The page ``fishfarm report --png`` draws: a tank's weight over time, each survey's weight
histogram standing at its date, the projection to the target weight, and the feed given per day."""
from __future__ import annotations

import numpy as np

from controller.plotting import pyplot, save_figure

DAY_S = 86_400.0


def draw_report(path: str, report: dict) -> None:
    plt = pyplot()
    fig, (ax, feed_ax) = plt.subplots(2, 1, figsize=(11, 7.5), sharex=True, constrained_layout=True,
                                      gridspec_kw={"height_ratios": [3, 1]})
    surveys = report["surveys"]
    t0 = surveys[0]["t"] if surveys else (report["feed_per_day"][0][1] if report["feed_per_day"] else 0.0)
    days = [(s["t"] - t0) / DAY_S for s in surveys]
    span = max([1.0, *days])
    width = 0.35 * span / max(1, len(surveys))          # a histogram's widest bar, in days
    for d, s in zip(days, surveys, strict=True):
        w = np.asarray(s["weights_g"], float)
        if w.size:
            counts, edges = np.histogram(w, bins=min(20, max(3, w.size // 5)))
            ax.barh(edges[:-1], counts / counts.max() * width, height=np.diff(edges), left=d,
                    align="edge", color="#7fb3d5", edgecolor="#2e86c1", lw=0.5)
    if surveys:
        means = [s["mean_weight_g"] for s in surveys]
        ax.plot(days, means, "o-", color="#1b4f72", label="mean weight")
        for d, s in zip(days, surveys, strict=True):
            label = f"{s['mean_weight_g']:.0f} g\nCV {s['cv_pct'] or 0:.0f} %\nn={s['fish']}"
            ax.annotate(label, (d, s["mean_weight_g"]), textcoords="offset points", xytext=(-8, 8), ha="right",
                        fontsize=8)
    _draw_fit(ax, report.get("fit"), t0)
    p = report.get("projection")
    if p is not None and p["days"] is not None and surveys:
        d_end = days[-1] + p["days"]
        ts = np.linspace(days[-1], d_end, 50)
        start = p.get("weight_g", surveys[-1]["mean_weight_g"])      # the fitted weight it grows from
        ax.plot(ts, start * np.exp(p["sgr_pct"] / 100 * (ts - days[-1])), "--",
                color="#c0392b", label=f"projection at {p['sgr_pct']:.2f} %/day: {p['target_g']:g} g on {p['date']}")
        ax.axhline(p["target_g"], color="#c0392b", lw=0.6, ls=":")
    ax.set_ylabel("weight (g)")
    title = f"tank {report['tank']} ({report['species']})"
    fit = report.get("fit")
    if fit is not None:                  # pooled over the window: what a manager plans on
        fcr = "n/a" if fit["fcr"] is None else f"{fit['fcr']:.2f}"
        title += (f": SGR {fit['sgr_pct_day']:.2f} ± {fit['sgr_ci_pct_day']:.2f} %/day, FCR {fcr}"
                  f" fitted over {fit['days']:.0f} days")
    elif report["intervals"]:
        last = report["intervals"][-1]
        fcr = "n/a" if last["fcr"] is None else f"{last['fcr']:.2f}"
        title += f": SGR {last['sgr_pct']:.2f} %/day, FCR {fcr} since the survey before"
    if report.get("grading"):
        title += " — GRADE (CV above limit)"
    ax.set_title(title if surveys else f"tank {report['tank']}: no survey yet")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", fontsize=9)
    feed = report["feed_per_day"]
    if feed:
        feed_ax.bar([(f[1] - t0) / DAY_S for f in feed], [f[2] / 1000 for f in feed], width=0.8, color="#58a55c")
    feed_ax.set_ylabel("feed (kg/day)")
    feed_ax.set_xlabel("days since the first survey" if surveys else "days")
    save_figure(fig, path)


def _draw_fit(ax, fit: dict | None, t0: float) -> None:
    """The growth fitted to the window's surveys, with its 95 % band: what the rations rest on."""
    if not fit or not fit.get("curve"):
        return
    t, w, ci = np.asarray(fit["curve"], float).T
    d = (t - t0) / DAY_S
    lo, hi = w / (1 + ci / 100), w * (1 + ci / 100)      # the interval is symmetric in log weight
    ax.fill_between(d, lo, hi, color="#f5b041", alpha=0.25, lw=0)
    ax.plot(d, w, "-", color="#d68910", lw=1.5,
            label=f"fitted growth ({fit['model']} model, {fit['surveys']} surveys), 95 % band")
