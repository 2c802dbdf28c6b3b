"""``fishfarm cleaner map --png MAP.png [--config farm.toml]``

The pond cleaner's coverage map from the ledger (``[store] path`` of the config): the cells
cleaned, those still to clean, those the mop-up gave up for good (the geofence refused them, or no
pass reached them), the water out of the robot's reach, the keep-outs, the dock, and the path the
robot followed in the current run. Prints the share cleaned and where the run
stands. Reads the ledger only; a running controller may keep writing it. Bad input (no
``[cleaning]`` section, a ledger that cannot be read, a map saved for another pond) exits 2 with
one line naming the fault.
"""
from __future__ import annotations

from pathlib import Path

import click

from controller.cli import CheckedGroup
from controller.errors import BadInput

CLEAN, DIRTY, OUT_OF_REACH = 255, 130, 60      # CoverageMap.image()'s values
GIVEN_UP = 100                                  # drawn here: dirty cells the mop-up will not try again


@click.group(cls=CheckedGroup)
def cleaner() -> None:
    """The pond-cleaning robot."""


@cleaner.command("map")
@click.option("--png", "png_path", required=True, metavar="MAP.png", help="where to draw the map")
@click.option("--config", "config_path", default="config/farm.toml", show_default=True, metavar="farm.toml")
def map_cmd(png_path: str, config_path: str) -> None:
    """Draw the coverage map and the path the cleaner followed."""
    from controller.cleaning.setup import fingerprint
    from controller.cli.output_paths import check_outputs
    from controller.config import load_config
    from controller.plotting import check_figure_name
    cfg = load_config(config_path)
    check_outputs({"--png": png_path}, [config_path, cfg.store.path])
    check_figure_name(png_path, "--png")
    s = cfg.cleaning
    if s is None:
        raise BadInput(config_path, "cleaning", "no [cleaning] section: this farm has no pond cleaner")
    from controller.cleaning.coverage_map import CoverageMap
    from controller.cleaning.geometry import pond_geometry
    geom = pond_geometry(s.outline, s.keepouts, where=config_path, key="cleaning.outline")
    saved, trace = _read_ledger(cfg.store.path)
    args = dict(cell_m=s.cell_m, brush_m=s.brush_m, body_radius_m=s.body_radius_m)
    if saved is not None and saved.fingerprint != fingerprint(s):
        raise BadInput(cfg.store.path, "cleaner", "the saved map is of another pond or plan than "
                                                  f"{config_path}'s [cleaning] (changed since)")
    cmap = CoverageMap(geom, **args)
    if saved is not None and saved.map is not None:
        try:
            cmap = CoverageMap.from_bytes(geom, saved.map, **args)
        except ValueError as exc:
            raise BadInput(cfg.store.path, "cleaner.map", str(exc)) from None
    minx, miny = cmap.origin
    rows, cols = cmap.image().shape
    extent = (minx, minx + cols * cmap.cell_m, miny, miny + rows * cmap.cell_m)
    title = "no cleaning run yet" if saved is None else (
        f"run {saved.run}: {100 * cmap.coverage():.1f} % cleaned, {saved.state}")
    image = cmap.image()
    image[(cmap.given_up & cmap.reachable & ~cmap.cleaned())[::-1]] = GIVEN_UP
    draw_map(png_path, geom, image, extent, trace, s.dock, title)
    click.echo(f"{title}; written: {png_path}")


def _read_ledger(path: str):
    from controller.store import Store
    if not Path(path).exists():
        raise BadInput(path, None, "no ledger there (the controller has not run with this config)")
    store = Store.reader(path)              # read only: a map changes nothing, migrates nothing
    try:
        saved = store.cleaner_progress()
        trace = store.cleaner_trace(saved.run) if saved is not None else None
    finally:
        store.close()
    return saved, trace


def draw_map(path: str, geom, image, extent, trace, dock, title: str) -> None:
    """The map on one page: cells by state, outline and keep-outs, the trace, the dock."""
    from controller.plotting import pyplot, save_figure
    plt = pyplot()
    from matplotlib.colors import ListedColormap

    colours = ListedColormap(["white", "#9db8c9", "#c9a56b", "#3a9a5b", "#8e44ad"])
    levels = {0: 0, OUT_OF_REACH: 1, DIRTY: 2, CLEAN: 3, GIVEN_UP: 4}
    shown = image.copy()
    for value, level in levels.items():
        shown[image == value] = level
    w, h = extent[1] - extent[0], extent[3] - extent[2]
    fig, ax = plt.subplots(figsize=(min(14.0, 3 + 10 * w / max(w, h)), min(10.0, 2 + 8 * h / max(w, h))),
                           constrained_layout=True)
    ax.imshow(shown, cmap=colours, vmin=0, vmax=4, extent=extent, origin="upper", interpolation="nearest")
    ax.plot(*geom.outline.exterior.xy, color="black", lw=1.5)
    for k in geom.keepouts:
        ax.fill(*k.exterior.xy, facecolor="#555555", edgecolor="black", lw=1, alpha=0.8)
    if trace is not None and len(trace):
        ax.plot(trace[:, 0], trace[:, 1], color="#c0392b", lw=0.8, label="path followed")
    ax.plot(*dock, marker="s", color="black", ms=8, ls="none", label="dock")
    from matplotlib.patches import Patch
    handles = [Patch(color="#3a9a5b", label="cleaned"), Patch(color="#c9a56b", label="to clean"),
               Patch(color="#8e44ad", label="given up (mop-up)"),
               Patch(color="#9db8c9", label="out of reach"), *ax.get_legend_handles_labels()[0]]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=9)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    save_figure(fig, path, dpi=120)
