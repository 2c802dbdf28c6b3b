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
from controller.cli.params import Finite
from controller.errors import BadInput

GRID_HEADER = ("x_mm", "y_mm", "z_mm", "u1", "v1", "u2", "v2")
# px: a grid clicked by hand reprojects within a few pixels, a lens's distortion left to DLT within
# tens at the corners; a digit mistyped is hundreds (an outside tester's +300 px went through, the
# 3-D distances up to 701 % wrong, exit 0)
MAX_ERROR_PX = 25.0


@click.command()
@click.option("--points", "points_path", required=True, metavar="GRID.csv",
              help="world points (mm) and their pixels in both images: x_mm,y_mm,z_mm,u1,v1,u2,v2")
@click.option("--out", "out_path", required=True, metavar="CALIB.json", help="where to write P1 and P2")
@click.option("--report", "report_path", default=None, metavar="REPORT.json",
              help="also write the validation report as JSON")
@click.option("--linear-only", is_flag=True,
              help="stop at the paper's linear least squares (no reprojection-error refinement)")
@click.option("--max-error", "max_error_px", type=Finite(min=0, min_open=True), default=MAX_ERROR_PX,
              show_default=True, metavar="PX", help="refuse a fit whose worst point reprojects further off than this")
def dlt(points_path: str, out_path: str, report_path: str | None, linear_only: bool, max_error_px: float) -> None:
    """Calibrate both cameras from >= 6 non-coplanar grid points (Ayache's DLT)."""
    from controller.cli.calib_io import save_calibration
    from controller.cli.output_paths import check_outputs, report_beside
    from vision.calib_file import StereoCalibration
    from vision.dlt import CalibrationInputError, calibrate_stereo

    check_outputs({"--out": out_path, "--report": report_path}, [points_path])
    grid = read_table(points_path, GRID_HEADER, limit=[WORLD_MAX] * 3 + [PIXELS_MAX] * 4)
    try:
        P1, P2, report = calibrate_stereo(grid[:, :3], grid[:, 3:5], grid[:, 5:7], refine=not linear_only)
    except CalibrationInputError as exc:
        raise BadInput(points_path, None, str(exc)) from None
    _refuse_a_wild_point(points_path, grid, P1, P2, report, max_error_px)
    rms = float(np.sqrt(np.mean(np.square(report.rms_px))))
    calib = StereoCalibration(P1=P1, P2=P2, rms_px=rms,
                              extra={"method": "dlt" if linear_only else "dlt+refine",
                                     "validation": report.to_json()})
    save_calibration(calib, out_path)
    if report_path is not None:
        from controller.atomic_files import write_text_atomically
        write_text_atomically(report_path, json.dumps(report.to_json(), indent=2) + "\n")
    with report_beside(out_path, report_path):
        click.echo(report.text())
        click.echo(f"written: {out_path}")


def _refuse_a_wild_point(points_path: str, grid: np.ndarray, P1, P2, report, max_error_px: float) -> None:
    """BadInput naming the grid line that reprojects worst, when it is beyond ``max_error_px``."""
    from vision.dlt import reprojection_errors
    errors = np.column_stack([reprojection_errors(P, grid[:, :3], grid[:, cols])
                              for P, cols in ((P1, slice(3, 5)), (P2, slice(5, 7)))])
    row, cam = np.unravel_index(int(errors.argmax()), errors.shape)
    if errors[row, cam] <= max_error_px:
        return
    u, v = grid[row, 3 + 2 * cam: 5 + 2 * cam]
    raise BadInput(points_path, f"line {row + 2}", f"(u{cam + 1}, v{cam + 1}) = ({u:g}, {v:g}) px is "
                                                   f"{errors[row, cam]:.1f} px off the fit (camera {cam + 1} RMS "
                                                   f"{report.rms_px[cam]:.1f} px, --max-error {max_error_px:g}): "
                                                   "mistyped, or another grid point's pixel?")
