"""The page ``fishfarm report --png`` draws, for a farm manager to read at a glance.

Left, over farm dates: the weight (each survey's histogram standing at its date, its mean, the
fitted growth with its 95 % band) above the feed per day. Right: the projection to the target
weight in a panel of its own (a month's projection on the same axis squeezed the week measured
into its left 5 %), or why there is none, and a table of the surveys with the uniformity.

No text may cover another: a survey's label over its histogram is drawn newest first and left out
where it would touch a text already there (surveys a day apart); the table has every figure.
"""
from __future__ import annotations

import datetime as dt
import textwrap

import numpy as np

from controller.plotting import pyplot, save_figure

DAY_S = 86_400.0
MIN_SPAN_D = 7.0          # the shortest time axis: one survey's histogram reads as one, not a wall
TABLE_ROWS = 12           # surveys listed, the newest; the rest counted
HISTOGRAMS = 24           # the newest surveys drawn as histograms, the older as their means on the line:
                          # a histogram each for 1,000 surveys took 30 s to draw (4,000: 6 minutes)
DPI = 110                 # the page's: the labels are placed with its renderer, in its pixels
HIST, MEAN, FIT, PROJ, FEED = "#7fb3d5", "#1b4f72", "#d68910", "#c0392b", "#58a55c"


def draw_report(path: str, report: dict, *, target_g: float | None = None, now: float | None = None) -> None:
    """``report`` as controller.production.tank_figures gives it; ``target_g`` the weight asked
    for (to say why no projection is drawn), ``now`` the farm time an empty page shows."""
    save_figure(page(report, target_g=target_g, now=now), path, dpi=DPI)


def page(report: dict, *, target_g: float | None = None, now: float | None = None):
    """The figure, laid out and frozen: its texts' boxes are where the file will have them."""
    plt = pyplot()
    fig = plt.figure(figsize=(13, 8), dpi=DPI, layout="constrained")
    grid = fig.add_gridspec(3, 2, width_ratios=[2.5, 1], height_ratios=[1.25, 1.25, 1])
    ax = fig.add_subplot(grid[0:2, 0])
    feed_ax = fig.add_subplot(grid[2, 0], sharex=ax)
    proj_ax = fig.add_subplot(grid[0, 1])
    side = fig.add_subplot(grid[1:3, 1])
    side.set_axis_off()
    surveys = report["surveys"]
    zone = farm_zone(report.get("utc_offset_h", 0.0))
    lo, hi, width = _time_axis(report, now, zone)
    labels = _draw_weights(ax, surveys, width)
    _draw_fit(ax, report.get("fit"))
    _draw_feed(feed_ax, report["feed_per_day"], zone)
    _date_axis(ax, feed_ax, lo, hi, zone)
    _draw_projection(proj_ax, report, target_g, zone)
    _draw_side(side, ax, report)
    fig.suptitle(_title(report), fontsize=13)
    if not surveys:
        before = report.get("surveys_before", 0)
        ax.text(0.5, 0.5, f"no survey since {report['since']} ({_n(before, 'survey')} before)" if "since" in report
                else "no surveys yet", transform=ax.transAxes, ha="center", va="center", fontsize=14, color="0.4")
    fig.draw_without_rendering()
    fig.set_layout_engine("none")       # frozen: the labels placed below stay where they are measured
    _place_labels(fig, ax, labels)
    return fig


def farm_zone(utc_offset_h: float) -> dt.tzinfo:
    """The farm's local time (config ``utc_offset_h``): the text report's days are its days, and a
    page in UTC put a survey at 01:00 local on the day before the one the text gave it."""
    return dt.timezone(dt.timedelta(hours=utc_offset_h))


def _zone_name(zone: dt.tzinfo) -> str:
    off = zone.utcoffset(None)
    if not off:
        return "UTC"
    minutes = int(off.total_seconds() // 60)
    sign, minutes = ("+" if minutes > 0 else "-"), abs(minutes)
    return f"UTC{sign}{minutes // 60}" + (f":{minutes % 60:02d}" if minutes % 60 else "")


def _time_axis(report: dict, now: float | None, zone: dt.tzinfo = dt.UTC) -> tuple[float, float, float]:
    """(first, last, histogram width), Unix seconds: the surveys and feed days, at least a week,
    each histogram as wide as 80 % of the gap to the next survey and 15 % of the axis at most."""
    ts = [s["t"] for s in report["surveys"]]
    points = ts + [_noon(f, zone) for f in report["feed_per_day"]]
    ts = ts[-HISTOGRAMS:]                       # the histograms drawn: their width
    if points:
        lo, hi = min(points), max(points)
    else:
        hi = now if now is not None else (report["empty_surveys"][-1]["t"] if report.get("empty_surveys")
                                          else dt.datetime.now(dt.UTC).timestamp())
        lo = hi - MIN_SPAN_D * DAY_S
    gaps = np.diff(sorted(ts))
    width = 0.15 * max(hi - lo, MIN_SPAN_D * DAY_S)
    if len(gaps) and gaps.min() > 0:
        width = min(width, 0.8 * gaps.min())
    if ts:
        hi = max(hi, max(ts) + width)
    if hi - lo < MIN_SPAN_D * DAY_S:            # centred on what there is
        grow = (MIN_SPAN_D * DAY_S - (hi - lo)) / 2
        lo, hi = lo - grow, hi + grow
    pad = 0.04 * (hi - lo)
    return lo - pad, hi + pad, width


def _draw_weights(ax, surveys: list[dict], width: float) -> list[tuple]:
    """The histograms and means; the labels to place, newest first: (x, y, text)."""
    labels = []
    tops = []
    for s in surveys[-HISTOGRAMS:]:
        d = _day(s["t"])
        w = np.asarray(s["weights_g"], float)
        top = s["mean_weight_g"]
        if w.size:
            counts, edges = np.histogram(w, bins=min(20, max(3, w.size // 5)))
            ax.barh(edges[:-1], counts / counts.max() * width / DAY_S, height=np.diff(edges), left=d,
                    align="edge", color=HIST, edgecolor="#2e86c1", lw=0.5)
            top = edges[-1]
        tops.append(top)
        labels.append((d + width / DAY_S / 2, top,
                       f"{_g(s['mean_weight_g'])}, CV {s['cv_pct'] or 0:.0f} %\n{_n(s['fish'], 'fish')}"))
    if surveys:
        ax.plot([_day(s["t"]) for s in surveys], [s["mean_weight_g"] for s in surveys],
                "o-" if len(surveys) <= 4 * HISTOGRAMS else "-", color=MEAN, label="mean weight")
        low = min(min(s["weights_g"] or [s["mean_weight_g"]]) for s in surveys[-HISTOGRAMS:])
        low = min(low, *(s["mean_weight_g"] for s in surveys))
        high = max(*tops, *(s["mean_weight_g"] for s in surveys))
        room = (high - low) or high or 1.0
        ax.set_ylim(max(0.0, low - 0.08 * room), high + 0.25 * room)     # the labels' room above
    else:
        ax.set_yticks([])
    ax.set_ylabel("weight (g)")
    return labels[::-1]


def _draw_fit(ax, fit: dict | None) -> None:
    """The growth fitted to the window's surveys, with its 95 % band: what the rations rest on."""
    if not fit or not fit.get("curve"):
        return
    t, w, ci = np.asarray(fit["curve"], float).T
    d = np.array([_day(x) for x in t])
    lo, hi = w / (1 + ci / 100), w * (1 + ci / 100)      # the interval is symmetric in log weight
    ax.fill_between(d, lo, hi, color=FIT, alpha=0.2, lw=0, label="95 % band of the fit")
    ax.plot(d, w, "-", color=FIT, lw=1.5, label=f"fitted growth ({fit['model']} model, {_n(fit['surveys'], 'survey')})")


def _draw_feed(ax, feed: list, zone: dt.tzinfo = dt.UTC) -> None:
    grams = [f[2] for f in feed]
    kg = bool(grams) and max(grams) >= 1000
    if feed:
        ax.bar([_day(_noon(f, zone)) for f in feed], [g / 1000 if kg else g for g in grams], width=0.8, color=FEED)
    else:
        ax.text(0.5, 0.5, "no feed recorded", transform=ax.transAxes, ha="center", va="center", color="0.4")
        ax.set_yticks([])
    ax.set_ylabel(f"feed ({'kg' if kg else 'g'}/day)")


def _dates(axis, most: int, zone: dt.tzinfo = dt.UTC) -> None:
    """Calendar dates a farmer reads: '28 May', the year once at the end, in the farm's time."""
    import matplotlib.dates as mdates
    locator = mdates.AutoDateLocator(minticks=2, maxticks=most, tz=zone)
    formatter = mdates.ConciseDateFormatter(locator, tz=zone)
    formatter.formats = formatter.zero_formats = ["%Y", "%b", "%d %b", "%H:%M", "%H:%M", "%S.%f"]
    formatter.offset_formats = ["", "%Y", "%Y", "%Y-%m-%d", "%Y-%m-%d", "%Y-%m-%d %H:%M"]
    axis.set_major_locator(locator)
    axis.set_major_formatter(formatter)


def _date_axis(ax, feed_ax, lo: float, hi: float, zone: dt.tzinfo = dt.UTC) -> None:
    _dates(feed_ax.xaxis, 9, zone)
    ax.set_xlim(_day(lo), _day(hi))
    ax.tick_params(labelbottom=False)
    feed_ax.set_xlabel(f"farm date ({_zone_name(zone)})")
    ax.grid(axis="x", color="0.9")
    feed_ax.grid(axis="x", color="0.9")


def _draw_projection(ax, report: dict, target_g: float | None, zone: dt.tzinfo = dt.UTC) -> None:
    """The path to the target weight on an axis of its own, or why there is none."""
    p, surveys = report.get("projection"), report["surveys"]
    why = no_projection(report, target_g)
    if why:
        ax.set_axis_off()
        ax.text(0.5, 0.5, "\n".join(textwrap.wrap(why, 40)), transform=ax.transAxes, ha="center", va="center",
                fontsize=10, color="0.3")
        return
    t0 = surveys[-1]["t"]
    start = p.get("weight_g", surveys[-1]["mean_weight_g"])
    days = np.linspace(0, p["days"], 60)
    ax.plot([_day(t0 + x * DAY_S) for x in days], start * np.exp(p["sgr_pct"] / 100 * days), "--", color=PROJ)
    ax.plot([_day(t0)], [start], "o", color=MEAN)
    ax.plot([_day(t0 + p["days"] * DAY_S)], [p["target_g"]], "o", color=PROJ)
    ax.axhline(p["target_g"], color=PROJ, lw=0.6, ls=":")
    ax.set_ylim(0, p["target_g"] * 1.15)
    ax.set_xlim(_day(t0) - 0.05 * p["days"], _day(t0) + 1.08 * p["days"])
    _dates(ax.xaxis, 4, zone)
    ax.set_ylabel("weight (g)")
    ax.set_title(f"{_g(p['target_g'])} on {p['date']}\nin {_days(p['days'])} at {p['sgr_pct']:.2f} %/day",
                 fontsize=10, color=PROJ)


def no_projection(report: dict, target_g: float | None) -> str | None:
    p = report.get("projection")
    if p is not None:
        if p["days"] is None:
            return f"no projection: the fish are not growing (SGR {p['sgr_pct']:.2f} %/day)"
        if p["days"] <= 0:
            return f"no projection: at the target already ({_g(p['weight_g'])}, target {_g(p['target_g'])})"
        return None
    n = len(report["surveys"])
    if target_g is None:
        return "no projection: no target weight (--target, or the tank's target_weight_g)"
    if n == 0:
        return f"no projection to {_g(target_g)}: no surveys yet"
    return f"no projection to {_g(target_g)}: growth needs two surveys, this tank has {_n(n, 'survey')}" + (
        " since " + report["since"] if "since" in report else "")


def _draw_side(ax, weight_ax, report: dict) -> None:
    """The legend of the weight panel, the table of surveys, the uniformity."""
    from matplotlib.patches import Patch
    handles, names = weight_ax.get_legend_handles_labels()
    if report["surveys"]:
        handles, names = [*handles, Patch(color=HIST)], [*names, "weights of a survey's fish"]
    y = 1.0
    if handles:
        ax.legend(handles, names, loc="upper left", frameon=False, fontsize=9, borderaxespad=0)
        y = 0.99 - 0.055 * len(handles)
    rows = report["surveys"][::-1]
    lines = [f"{'date':<11}{'mean':>8}{'CV':>6}{'fish':>7}"]
    lines += [f"{s['date']:<11}{_g(s['mean_weight_g']):>8}{(s['cv_pct'] or 0):>4.0f} %{s['fish']:>7}"
              for s in rows[:TABLE_ROWS]]
    if len(rows) > TABLE_ROWS:
        lines.append(f"and {_n(len(rows) - TABLE_ROWS, 'earlier survey')}")
    empty = report.get("empty_surveys") or []
    if empty:
        few = "no fish" if all(not e.get("fish") for e in empty) else "too few fish"
        lines.append(f"{_n(len(empty), 'survey')} counted {few} (newest {empty[-1]['date']})")
    if rows:
        ax.text(0, y, "Surveys, newest first", transform=ax.transAxes, va="top", fontsize=10, weight="bold")
        ax.text(0, y - 0.05, "\n".join(lines), transform=ax.transAxes, va="top", family="monospace", fontsize=9)
    if "grading" in report:
        cv = report["surveys"][-1]["cv_pct"] or 0
        grade = report["grading"]
        ax.text(0, 0, (f"GRADE: CV {cv:.0f} % above {report['grading_cv_pct']:g} %" if grade
                       else f"uniform: CV {cv:.0f} % within {report['grading_cv_pct']:g} %"),
                transform=ax.transAxes, va="bottom", fontsize=10, color=PROJ if grade else "0.2",
                weight="bold" if grade else "normal")


def _place_labels(fig, ax, labels: list[tuple]) -> None:
    """Each label over its histogram, newest first, where it touches no text already drawn and
    stays in the panel; else left out (the side table has its figures)."""
    renderer = fig.canvas.get_renderer()
    taken = [t.get_window_extent(renderer) for t in texts(fig)]
    inside = ax.get_window_extent(renderer)
    for x, y, label in labels:
        text = ax.text(x, y, label, ha="center", va="bottom", fontsize=8, color=MEAN)
        box = text.get_window_extent(renderer)
        if box.x1 > inside.x1:                  # the newest, at the right edge: leftwards
            text.set_horizontalalignment("right")
            box = text.get_window_extent(renderer)
        fits = inside.x0 <= box.x0 and box.x1 <= inside.x1 and box.y1 <= inside.y1
        if not fits or any(box.overlaps(b) for b in taken):
            text.remove()
        else:
            taken.append(box)


def texts(fig) -> list:
    """The texts ``fig`` draws: titles, labels, legends, notes, and tick labels in their axis's
    range (matplotlib keeps labels for ticks beyond it, drawn nowhere); none empty or hidden."""
    from matplotlib.text import Text
    renderer = fig.canvas.get_renderer()
    ticks = {}                           # a tick label's id: its axis is x (True) or y
    for ax in fig.axes:
        for axis, is_x in ((ax.xaxis, True), (ax.yaxis, False)):
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                ticks.update({id(tick.label1): (ax, is_x), id(tick.label2): (ax, is_x)})
    out = []
    for t in fig.findobj(Text):
        if not t.get_visible() or not t.get_text().strip():
            continue
        if id(t) in ticks:
            ax, is_x = ticks[id(t)]
            box, frame = t.get_window_extent(renderer), ax.get_window_extent(renderer)
            mid = (box.x0 + box.x1) / 2 if is_x else (box.y0 + box.y1) / 2
            lo, hi = (frame.x0, frame.x1) if is_x else (frame.y0, frame.y1)
            if not lo - 0.5 <= mid <= hi + 0.5:
                continue
        out.append(t)
    return out


def _title(report: dict) -> str:
    head = f"Tank {report['tank']} ({report['species']})"
    fit = report.get("fit")
    if fit is not None:
        fcr = "n/a" if fit["fcr"] is None else f"{fit['fcr']:.2f}"
        return (f"{head}: growth {fit['sgr_pct_day']:.2f} ± {fit['sgr_ci_pct_day']:.2f} %/day, FCR {fcr}, "
                f"fitted to {_n(fit['surveys'], 'survey')} over {_days(fit['days'])}")
    if report["intervals"]:
        last = report["intervals"][-1]
        fcr = "n/a" if last["fcr"] is None else f"{last['fcr']:.2f}"
        return f"{head}: growth {last['sgr_pct']:.2f} %/day, FCR {fcr} since the survey before"
    n = len(report["surveys"])
    return f"{head}: {_n(n, 'survey')}" if n else f"{head}: no surveys yet"


def _day(t: float) -> float:
    """Unix seconds as matplotlib's date number (days since its epoch, 1970 in UTC)."""
    import matplotlib.dates as mdates
    return mdates.date2num(dt.datetime.fromtimestamp(t, dt.UTC))


def _noon(feed_day: tuple, zone: dt.tzinfo = dt.UTC) -> float:
    """A farm day's bar stands at its local noon (a day not named by its date: at its first feed)."""
    date, first, _ = feed_day
    try:
        return dt.datetime.fromisoformat(date).replace(hour=12, tzinfo=zone).timestamp()
    except ValueError:
        return first


def _g(w: float) -> str:
    if w >= 1000:
        return f"{w / 1000:.2f} kg"
    return f"{w:.1f} g" if w < 10 else f"{w:.0f} g"


def _days(d: float) -> str:
    shown = f"{d:.1f}" if d < 10 else f"{d:.0f}"
    return f"{shown} day" if shown in ("1", "1.0") else f"{shown} days"


def _n(k: int, noun: str) -> str:
    """1 survey, 2 surveys; fish stay fish."""
    if k == 1 or noun.endswith("fish"):
        return f"{k} {noun}"
    return f"{k} {noun}s"

