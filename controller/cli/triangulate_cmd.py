"""``fishfarm triangulate --calib CALIB.json --pairs PAIRS.csv [--out OUT.csv]``

Each pixel pair ``u1,v1,u2,v2`` becomes ``x_mm,y_mm,z_mm,residual_px`` by the least squares of the
paper's eq. (6), in the calibration's world frame, one row per input row in order. Pixels are
undistorted first when CALIB.json has D1/D2. Without --out the CSV goes to stdout.
"""
from __future__ import annotations

import click
import numpy as np

from controller.cli.csvio import PIXELS_MAX, read_table, write_table

PAIRS_HEADER = ("u1", "v1", "u2", "v2")
OUT_HEADER = ("x_mm", "y_mm", "z_mm", "residual_px")


@click.command()
@click.option("--calib", "calib_path", required=True, metavar="CALIB.json", help="P1, P2 (and optional K, D)")
@click.option("--pairs", "pairs_path", required=True, metavar="PAIRS.csv", help="matched pixels: u1,v1,u2,v2")
@click.option("--out", "out_path", default=None, metavar="OUT.csv", help="output CSV (default: stdout)")
def triangulate(calib_path: str, pairs_path: str, out_path: str | None) -> None:
    """3-D points of matched pixel pairs, with the reprojection residual in pixels."""
    from controller.cli.calib_io import load_calibration
    from controller.cli.output_paths import check_outputs
    from vision.triangulation import triangulate_calibrated
    check_outputs({"--out": out_path}, [calib_path, pairs_path])
    calib = load_calibration(calib_path)
    pairs = read_table(pairs_path, PAIRS_HEADER, limit=PIXELS_MAX)
    points, residual = triangulate_calibrated(calib, pairs[:, :2], pairs[:, 2:4])
    write_table(out_path, OUT_HEADER, np.c_[points, residual])
    beyond = np.flatnonzero(~np.isfinite(residual))
    if len(beyond):
        rows = ", ".join(str(r + 2) for r in beyond[:5]) + (" ..." if len(beyond) > 5 else "")
        click.echo(f"fishfarm triangulate: warning: {len(beyond)} pairs (lines {rows} of {pairs_path}) lie beyond "
                   f"where {calib_path}'s lens model reaches (D1/D2 fold back there): written as nan", err=True)
