"""``fishfarm calibrate tower --points REF.csv --out TOWER.json``

The tower camera's homography, pixel (u, v, 1) -> pond plane (x_m, y_m, 1), from >= 4 surveyed
reference points (REF.csv: ``u,v,x_m,y_m``), by vision.tower.fit_tower. Writes ``{"H": 3x3}`` with
``rms_m``, ``max_m`` and ``points``; prints the error on the pond in metres (RMS, worst, and each
point when there are few). Bad input exits 2 with one line naming the file, the field and the fault.
"""
from __future__ import annotations

import json

import click

from controller.cli.csvio import PIXELS_MAX, WORLD_MAX, read_table
from controller.errors import BadInput

REF_HEADER = ("u", "v", "x_m", "y_m")
LIST_AT_MOST = 12      # points listed one by one up to this many


@click.command()
@click.option("--points", "points_path", required=True, metavar="REF.csv",
              help="surveyed reference points: pixel and pond position (m): u,v,x_m,y_m")
@click.option("--out", "out_path", required=True, metavar="TOWER.json", help="where to write H")
def tower(points_path: str, out_path: str) -> None:
    """Map the tower camera's pixels to the pond plane from >= 4 surveyed points (homography)."""
    from controller.cli.output_paths import check_outputs
    from vision.tower import TowerInputError, fit_tower
    check_outputs({"--out": out_path}, [points_path])
    ref = read_table(points_path, REF_HEADER, limit=[PIXELS_MAX] * 2 + [WORLD_MAX] * 2)
    try:
        fit = fit_tower(ref[:, :2], ref[:, 2:])
    except TowerInputError as exc:
        raise BadInput(points_path, None, str(exc)) from None
    doc = {"H": fit.H.tolist(), "rms_m": fit.rms_m, "max_m": fit.max_m, "points": len(ref)}
    from controller.atomic_files import write_text_atomically
    write_text_atomically(out_path, json.dumps(doc, indent=2) + "\n")
    if len(ref) <= LIST_AT_MOST:
        for k, ((u, v, x, y), r) in enumerate(zip(ref, fit.residuals_m, strict=True), 1):
            click.echo(f"point {k}: ({u:.1f}, {v:.1f}) px -> ({x:.3f}, {y:.3f}) m: error {r:.3f} m")
    click.echo(f"{len(ref)} points: error on the pond RMS {fit.rms_m:.3f} m, worst {fit.max_m:.3f} m "
               f"(point {int(fit.residuals_m.argmax()) + 1})")
    click.echo(f"written: {out_path}")
