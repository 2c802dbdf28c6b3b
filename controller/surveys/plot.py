"""``--plot HIST.png``: the survey on one page — weight and length histograms, the mean, the 95 %
interval on mean weight and the count, large enough to read at a glance on a phone."""
from __future__ import annotations

from controller.plotting import pyplot, save_figure


def _fmt(x, unit: str, digits: int = 1) -> str:
    return "n/a" if x is None else f"{x:.{digits}f} {unit}"


def plot_survey(summary: dict, path: str) -> None:
    plt = pyplot()
    from matplotlib.ticker import MaxNLocator

    w, L = summary["weight_g"], summary["length_cm"]
    n = summary["count"]
    fig, (ax_w, ax_l) = plt.subplots(1, 2, figsize=(11, 4.8), constrained_layout=True)
    for ax, part, unit, colour in ((ax_w, w, "g", "#2a7ab0"), (ax_l, L, "cm", "#3a9a5b")):
        edges, counts = part["histogram"]["edges"], part["histogram"]["counts"]
        if counts:
            ax.stairs(counts, edges, fill=True, color=colour, alpha=0.75)
        if part["mean"] is not None:
            ax.axvline(part["mean"], color="black", lw=2, label=f"mean {_fmt(part['mean'], unit)}")
        ax.set_xlabel("weight (g)" if unit == "g" else "fork length (cm)")
        per = summary.get("statistics_per", "fish")
        ax.set_ylabel("fish" if per == "fish" else "fish (one per track)")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))        # fish come whole
        ax.grid(axis="y", alpha=0.3)
    if w.get("ci"):
        lo, hi = w["ci"]
        ax_w.axvspan(lo, hi, color="orange", alpha=0.35, label=f"95 % CI {lo:.1f}–{hi:.1f} g")
    for ax in (ax_w, ax_l):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper right")
    prec = summary.get("precision", {})
    more = prec.get("more_fish")
    need = "" if more is None else (" — within ±2 %" if more == 0 else f" — {more} more fish for ±2 %")
    title = (f"{summary.get('species_name', summary['species'])}, {summary['setup']}: {n} fish, "
             f"mean {_fmt(w['mean'], 'g')} (CV {_fmt(None if w.get('cv') is None else 100 * w['cv'], '%', 0)})"
             f", mean length {_fmt(L['mean'], 'cm')}{need}")
    fig.suptitle(title, fontsize=12)
    if n == 0:
        for ax in (ax_w, ax_l):
            ax.text(0.5, 0.5, "no fish measured", ha="center", va="center", transform=ax.transAxes, fontsize=14)
    save_figure(fig, path)
