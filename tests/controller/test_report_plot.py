"""The report's page read as a farm manager reads it, checked on the figure's structure (its texts,
their boxes as matplotlib's renderer lays them out, its axes), not its pixels: calendar dates, no
text over another, histograms a reader can see, the projection beside the data, not over them, and
a word where there is nothing to draw."""
from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from controller.report_plot import page, texts

DAY = 86_400.0
T = 1_780_000_000.0                      # 2026-05-28T20:26:40Z


def survey(t: float, mean: float, n: int = 81, cv: float = 22.0, seed: int = 0) -> dict:
    w = np.random.default_rng(seed).normal(mean, mean * cv / 100, n).clip(mean / 5)
    return {"t": t, "date": time.strftime("%Y-%m-%d", time.gmtime(t)), "fish": n, "mean_weight_g": float(w.mean()),
            "cv_pct": cv, "k": 1.3, "stock": 2400, "weights_g": [float(x) for x in w]}


def report(surveys: list[dict], *, feed_days=(), projection=None, fit=None, **more) -> dict:
    feed = [(time.strftime("%Y-%m-%d", time.gmtime(T + d * DAY)), T + d * DAY, 800.0) for d in feed_days]
    out = {"tank": "T1", "species": "sparus_aurata", "surveys": surveys, "empty_surveys": [], "feed_per_day": feed,
           "intervals": [{"sgr_pct": 2.0, "fcr": 1.1}] * max(0, len(surveys) - 1), "grading_cv_pct": 30.0, **more}
    if surveys:
        out["grading"] = False
    if projection is not None:
        out["projection"] = projection
    if fit is not None:
        out["fit"] = fit
    return out


def read(fig) -> tuple[list[str], list]:
    """The texts drawn and, for each, its box in the page's pixels."""
    renderer = fig.canvas.get_renderer()
    shown = texts(fig)
    return [t.get_text() for t in shown], [t.get_window_extent(renderer) for t in shown]


def assert_no_text_covers_another(fig) -> None:
    words, boxes = read(fig)
    assert len(words) > 5
    touching = [(words[i], words[j]) for i, j in itertools.combinations(range(len(words)), 2)
                if boxes[i].overlaps(boxes[j])]
    assert touching == []


def assert_dates_on_the_time_axis(fig, *days: float) -> None:
    """Calendar dates ('28 May'), the year written once, and the days asked for in view."""
    import matplotlib.dates as mdates
    weight_ax, feed_ax = fig.axes[0], fig.axes[1]
    assert isinstance(feed_ax.xaxis.get_major_formatter(), mdates.ConciseDateFormatter)
    ticks = [t for t in read(fig)[0] if any(m in t for m in ("May", "Jun", "Jul", "Aug", "Nov", "Dec"))]
    assert len(ticks) >= 2 and "2026" in read(fig)[0]
    lo, hi = weight_ax.get_xlim()
    assert all(lo <= T / DAY + d <= hi for d in days) and feed_ax.get_xlim() == (lo, hi)


def test_one_survey_a_target_no_projection_and_why(tmp_path):
    """Reported: the label sat on the y-axis label, the histogram filled the whole axis, and a
    --target 100 with one survey drew nothing and said nothing."""
    fig = page(report([survey(T, 42)], feed_days=range(-3, 3)), target_g=100)
    words, _ = read(fig)
    assert "no projection to 100 g: growth needs two\nsurveys, this tank has 1 survey" in words
    assert any(w.startswith("Tank T1 (sparus_aurata): 1 survey") for w in words)
    assert sum("CV 22 %\n81 fish" in w for w in words) == 1            # its label is drawn
    assert_no_text_covers_another(fig)
    assert_dates_on_the_time_axis(fig, -3, 0, 2)
    [bars] = fig.axes[0].containers                                    # the histogram: a day wide, not the axis
    widest = max(b.get_width() for b in bars)
    lo, hi = fig.axes[0].get_xlim()
    assert 0.5 <= widest <= 0.2 * (hi - lo)


def test_two_surveys_a_day_apart_with_a_month_s_projection():
    """Reported: the two labels overprinted, the histograms were slivers, the projection squeezed
    the data into the left 5 % of the axis, and the title said 'fitted over 1 days'."""
    s = [survey(T, 40), survey(T + 1.2 * DAY, 41, n=70, seed=1)]
    curve = [[T + f * 1.2 * DAY, 40 + f, 5.0] for f in np.linspace(0, 1, 20)]
    fit = {"sgr_pct_day": 3.13, "sgr_ci_pct_day": 5.5, "fcr": 0.22, "days": 1.2, "surveys": 2, "model": "feed",
           "curve": curve}
    days = 100 * np.log(100 / 41) / 3.13                   # 28.5
    proj = {"target_g": 100.0, "sgr_pct": 3.13, "days": days, "date": "2026-06-28", "weight_g": 41.0, "basis": "fit"}
    fig = page(report(s, feed_days=range(-2, 2), projection=proj, fit=fit), target_g=100)
    words, _ = read(fig)
    assert any("fitted to 2 surveys over 1.2 days" in w for w in words)
    assert "100 g on 2026-06-28\nin 28 days at 3.13 %/day" in words
    assert_no_text_covers_another(fig)
    assert_dates_on_the_time_axis(fig, 0, 1.2)
    weight_ax, _, proj_ax, _ = fig.axes
    lo, hi = weight_ax.get_xlim()                          # the measured days fill the weight panel
    assert hi - lo < 10 and (T / DAY + 1.2 - lo) / (hi - lo) > 0.5
    bars = [b for c in weight_ax.containers for b in c]
    assert min(max(b.get_width() for b in c) for c in weight_ax.containers) >= 0.5 and len(bars) > 6
    # the projection's month on its own axis, from the newest survey to the target's date
    line = proj_ax.lines[0]
    assert line.get_xdata()[0] == pytest.approx(T / DAY + 1.2) and line.get_xdata()[-1] == pytest.approx(
        T / DAY + 1.2 + days)
    assert line.get_ydata()[-1] == pytest.approx(100, rel=1e-3)


def test_no_surveys_says_so_on_a_week_of_dates():
    """Reported: a blank weight panel and a feed bar at 'day 0' on an axis from -0.4 to 0.4."""
    fig = page(report([], feed_days=[0]), target_g=100, now=T + DAY)
    words, _ = read(fig)
    assert "no surveys yet" in words and "no projection to 100 g: no surveys yet" in words
    assert_no_text_covers_another(fig)
    assert_dates_on_the_time_axis(fig, 0)
    lo, hi = fig.axes[0].get_xlim()
    assert hi - lo >= 7
    fig = page(report([]), now=T)
    words, _ = read(fig)
    assert "no feed recorded" in words and any("no target weight" in w for w in words)
    assert_dates_on_the_time_axis(fig, -6)


def test_many_surveys_each_labelled_where_there_is_room_all_in_the_table():
    s = [survey(T + 7 * k * DAY, 20 * 1.02 ** (7 * k), n=60 + k, seed=k) for k in range(14)]
    proj = {"target_g": 400.0, "sgr_pct": 1.96, "days": 67.0, "date": "2026-11-02", "weight_g": 120.0,
            "basis": "fit"}
    fig = page(report(s, feed_days=range(95), projection=proj), target_g=400)
    words, _ = read(fig)
    assert_no_text_covers_another(fig)
    assert_dates_on_the_time_axis(fig, 0, 91)
    labels = [w for w in words if w.endswith(" fish") and "CV" in w]
    assert labels[0].endswith(f"{s[-1]['fish']} fish") and 4 <= len(labels) <= 14      # the newest first
    [table] = [w for w in words if w.startswith("date")]
    assert table.count("\n") == 13 and table.endswith("and 2 earlier surveys")


@pytest.mark.parametrize(("grams", "unit"), [(800.0, "feed (g/day)"), (2500.0, "feed (kg/day)")])
def test_the_feed_s_unit_follows_its_size(grams, unit):
    r = report([survey(T, 42)])
    r["feed_per_day"] = [("2026-05-28", T, grams)]
    assert unit in read(page(r))[0]
