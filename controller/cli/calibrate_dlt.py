"""``fishfarm calibrate dlt --points GRID.csv --out CALIB.json [--report REPORT.json]``

Ayache's DLT per camera from a measured grid (paper eqs. (1)-(2)), refined on reprojection error,
then a validation report on stdout: reprojection RMS per camera, the relative error of every
grid distance reconstructed in 3-D (median, p95, max %), the grid's shape (thickness off its plane
over its extent; below 0.05 the grid is refused, exit 2), and the same errors out of sample: a
10-fold held-out check where each point is predicted by a calibration that never saw it.
"""
from __future__ import annotations

import json

import click
import numpy as np

from controller.cli.csvio import PIXELS_MAX, WORLD_MAX, read_table
from controller.errors import BadInput

GRID_HEADER = ("x_mm", "y_mm", "z_mm", "u1", "v1", "u2", "v2")


@click.command()
@click.option("--points", "points_path", required=True, metavar="GRID.csv",
              help="world points (mm) and their pixels in both images: x_mm,y_mm,z_mm,u1,v1,u2,v2")
@click.option("--out", "out_path", required=True, metavar="CALIB.json", help="where to write P1 and P2")
@click.option("--report", "report_path", default=None, metavar="REPORT.json",
              help="also write the validation report as JSON")
@click.option("--linear-only", is_flag=True,
              help="stop at the paper's linear least squares (no reprojection-error refinement)")
def dlt(points_path: str, out_path: str, report_path: str | None, linear_only: bool) -> None:
    """Calibrate both cameras from >= 6 non-coplanar grid points (Ayache's DLT)."""
    from controller.cli.calib_io import save_calibration
    from controller.cli.output_paths import check_outputs
    from vision.calib_file import StereoCalibration
    from vision.dlt import CalibrationInputError, calibrate_stereo

    check_outputs({"--out": out_path, "--report": report_path}, [points_path])
    grid = read_table(points_path, GRID_HEADER, limit=[WORLD_MAX] * 3 + [PIXELS_MAX] * 4)
    try:
        P1, P2, report = calibrate_stereo(grid[:, :3], grid[:, 3:5], grid[:, 5:7], refine=not linear_only)
    except CalibrationInputError as exc:
        raise BadInput(points_path, None, str(exc)) from None
    rms = float(np.sqrt(np.mean(np.square(report.rms_px))))
    calib = StereoCalibration(P1=P1, P2=P2, rms_px=rms,
                              extra={"method": "dlt" if linear_only else "dlt+refine",
                                     "validation": report.to_json()})
    save_calibration(calib, out_path)
    if report_path is not None:
        from controller.atomic_files import write_text_atomically
        write_text_atomically(report_path, json.dumps(report.to_json(), indent=2) + "\n")
    click.echo(report.text())
    click.echo(f"written: {out_path}")
