"""``fishfarm report --tank T [--since ISO|DURATION] [--target G] [--png REPORT.png] [--json]
[--config farm.toml]``

A tank's production figures from the ledger (controller/production.py): each survey (fish, mean
weight, CV, condition factor, stock), between consecutive surveys the growth (SGR), feed given,
biomass gain and FCR (the biological; the net beside it where fish died), the same fitted to the
surveys of the growth window with their 95 % intervals, size uniformity against ``[feeding]
grading_cv_pct``, and the projection to the target weight (``--target`` or the tank's
``target_weight_g``) at the fitted SGR. ``--png`` draws weight over time with each survey's
histogram, the projection and the feed per day. A ``--since`` duration goes back from the later of
the wall clock and the ledger's latest entry (controller/history.ledger_now).
Reads the ledger only; a running controller may keep writing it. Bad input exits 2 with one line.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import click

from controller.errors import BadInput


def _net(figures: dict) -> str:
    """The net FCR beside the biological one, where fish died meanwhile (controller/production.py)."""
    if not figures.get("died_g"):
        return ""
    net = figures.get("fcr_net")
    return ", net n/a (no gain kept)" if net is None else f", net {net:.2f} ({figures['died_g']:.0f} g died)"


def _few(empty: list[dict]) -> str:
    """The surveys that weigh nothing: 'M that counted none', or with some that counted a handful
    (fewer than [surveys] min_weighed_fish) 'M that counted too few fish to weigh the tank (K none)'."""
    none = sum(1 for e in empty if not e.get("fish"))
    if none == len(empty):
        return f"{len(empty)} that counted none"
    return f"{len(empty)} that counted too few fish to weigh the tank" + (f" ({none} none)" if none else "")


def text(report: dict, target_g: float | None = None) -> str:
    empty = report.get("empty_surveys") or []
    n = len(report["surveys"])
    lines = [f"{report['tank']} ({report['species']}): {n} survey{'' if n == 1 else 's'}"
             + (f" that counted fish, {_few(empty)}" if empty else "")]
    for s in report["surveys"]:
        lines.append(f"  survey {s['date']}: {s['fish']} fish, mean {s['mean_weight_g']:.1f} g, "
                     f"CV {s['cv_pct'] or 0:.1f} %, K {s['k']:.2f}, stock {s['stock']}")
    for i in report["intervals"]:
        fcr = _no_fcr(i) if i["fcr"] is None else f"{i['fcr']:.2f}{_net(i)}"
        lines.append(f"  {i['date1']} -> {i['date2']} ({i['days']:.1f} d): SGR {i['sgr_pct']:.2f} %/day, "
                     f"feed {i['feed_g']:.0f} g, biomass gain {i['gain_g']:.0f} g, FCR {fcr}")
    f = report.get("fit")
    if f is not None:
        lo, hi = (_bound(x) for x in f["fcr_ci"])
        fcr = _no_fcr(f) if f["fcr"] is None else f"{f['fcr']:.2f} ({lo}-{hi}, 95 %){_net(f)}"
        lines.append(f"  fitted to {f['surveys']} surveys since {f['since']} ({f['days']:.1f} d, {f['fish']} fish): "
                     f"SGR {f['sgr_pct_day']:.2f} ± {f['sgr_ci_pct_day']:.2f} %/day, FCR {fcr}")
    if "grading" in report:
        cv = report["surveys"][-1]["cv_pct"] or 0
        verdict = "GRADE: above" if report["grading"] else "within"
        lines.append(f"  uniformity: CV {cv:.1f} % ({verdict} {report['grading_cv_pct']:g} %)")
    p = report.get("projection")
    if p is not None and not p.get("reached"):
        when = "not growing: no date" if p["days"] is None else f"in {p['days']:.0f} days, {p['date']}"
        lines.append(f"  projection: {p['target_g']:g} g at {p['sgr_pct']:.2f} %/day {when}")
    elif report["surveys"]:        # why there is none (no target, one survey), or the target reached
        from controller.report_plot import no_projection
        lines.append(f"  {no_projection(report, target_g)}")
    if empty:
        after = [e for e in empty if report["surveys"] and e["t"] > report["surveys"][-1]["t"]]
        newest = empty[-1]
        head = "no fish counted" if not newest.get("fish") else \
            f"too few fish to weigh the tank ({newest['fish']})"
        lines.append(f"  {head}: newest {newest['date']}"
                     + (f", {len(after)} since the last survey that counted fish" if after else "")
                     + " (cameras blocked or fouled, lights, turbid water?)")
    if not report["surveys"] and not empty:
        before = report.get("surveys_before", 0)
        lines.append(f"  no survey of this tank since {report['since']} ({before} before)" if "since" in report
                     else "  no survey in the ledger for this tank")
    return "\n".join(lines)


def _no_fcr(figures: dict) -> str:
    return "n/a (no feed recorded)" if not figures.get("feed_g") else "n/a (no gain)"


def _bound(x: float | None) -> str:
    return "unbounded" if x is None else f"{x:.2f}"


@click.command()
@click.option("--tank", "tank_id", required=True, help="the tank's id")
@click.option("--since", default=None, metavar="ISO|DURATION", help="surveys from this time, or this long ago (30d).")
@click.option("--target", "target_g", type=float, default=None, help="harvest weight, g (default: the tank's)")
@click.option("--png", "png_path", default=None, metavar="REPORT.png", help="also draw the report")
@click.option("--json", "as_json", is_flag=True, help="print the figures as JSON")
@click.option("--config", "config_path", default="config/farm.toml", show_default=True, metavar="farm.toml")
def report(tank_id, since, target_g, png_path, as_json, config_path) -> None:
    """A tank's growth, feed conversion, uniformity and projection, between its surveys."""
    from controller.cli.output_paths import check_outputs
    from controller.config import load_config
    from controller.history import ledger_now, parse_time
    from controller.production import tank_figures
    from controller.store import Store
    cfg = load_config(config_path)
    from controller.farm_setup import check_species_file
    check_species_file(cfg)                    # as `run` refuses it: a misspelt species is another fish
    check_outputs({"--png": png_path}, [config_path, cfg.store.path])
    if png_path:
        from controller.plotting import check_figure_name
        check_figure_name(png_path, "--png")
    if tank_id not in {t.id for t in cfg.tanks}:
        raise BadInput(config_path, "--tank", f"no tank {tank_id!r} (tanks: {', '.join(t.id for t in cfg.tanks)})")
    if target_g is not None and not 0 < target_g < math.inf:
        raise BadInput("--target", None, f"must be a finite weight above 0 g, not {target_g:g}")
    now = ledger_now(cfg.store.path)
    start = parse_time(since, "--since", now, durations=True) if since is not None else None   # as history reads it
    if not Path(cfg.store.path).exists():
        raise BadInput(cfg.store.path, None, "no ledger there (the controller has not run with this config)")
    store = Store.reader(cfg.store.path, cfg.surveys.min_weighed_fish)
    try:
        data = tank_figures(cfg, store, tank_id, start, target_g)
    finally:
        store.close()
    target = target_g if target_g is not None else cfg.tank(tank_id).target_weight_g
    click.echo(json.dumps(data) if as_json else text(data, target))
    if png_path:
        from controller.report_plot import draw_report
        draw_report(png_path, data, target_g=target, now=now)
        if not as_json:
            click.echo(f"written: {png_path}")
