"""``fishfarm calibrate tower --points REF.csv --out TOWER.json``

The tower camera's homography, pixel (u, v, 1) -> pond plane (x_m, y_m, 1), from >= 4 surveyed
reference points (REF.csv: ``u,v,x_m,y_m``), by vision.tower.fit_tower. Writes ``{"H": 3x3}`` with
``rms_m``, ``max_m`` and ``points``; prints the error on the pond in metres (RMS, worst, and each
point when there are few). Bad input exits 2 with one line naming the file, the field and the fault.
"""
from __future__ import annotations

import json

import click
import numpy as np

from controller.cli.csvio import PIXELS_MAX, WORLD_MAX, read_table
from controller.cli.params import Finite, image_size_option
from controller.errors import BadInput

REF_HEADER = ("u", "v", "x_m", "y_m")
MAX_ERROR_M = 1.0      # a point this far off the others' fit is a typo, not a tape measure's error
LIST_AT_MOST = 12      # points listed one by one up to this many


@click.command()
@click.option("--points", "points_path", required=True, metavar="REF.csv",
              help="surveyed reference points: pixel and pond position (m): u,v,x_m,y_m")
@click.option("--out", "out_path", required=True, metavar="TOWER.json", help="where to write H")
@click.option("--image-size", "size", default=None, metavar="WxH", callback=image_size_option,
              help="the camera's frame size the pixels were read on (kept: other frames are refused)")
@click.option("--max-error", "max_error_m", type=Finite(min=0, min_open=True), default=MAX_ERROR_M,
              show_default=True, metavar="M", help="refuse a fit whose worst point is further off than this (m)")
@click.option("--mirrored-image", is_flag=True, help="the camera mirrors its picture (a setting some have): "
              "the pond is then seen mirrored, and that is right")
def tower(points_path: str, out_path: str, size: tuple[int, int] | None, max_error_m: float,
          mirrored_image: bool) -> None:
    """Map the tower camera's pixels to the pond plane from >= 4 surveyed points (homography)."""
    from controller.cli.output_paths import check_outputs, report_beside
    from vision.tower import TowerInputError, fit_tower, seen_from_above
    check_outputs({"--out": out_path}, [points_path])
    ref = read_table(points_path, REF_HEADER, limit=[PIXELS_MAX] * 2 + [WORLD_MAX] * 2)
    try:
        fit = fit_tower(ref[:, :2], ref[:, 2:])
    except TowerInputError as exc:
        raise BadInput(points_path, None, str(exc)) from None
    if seen_from_above(fit.H, ref[:, :2]) == mirrored_image:
        raise BadInput(points_path, None, "the fit sees the pond mirrored, as no camera above it does: is an "
                                          "axis measured the other way (x from the other end, y downwards)? "
                                          "(a camera set to mirror its picture: --mirrored-image)"
                       if not mirrored_image else "--mirrored-image, but the fit sees the pond as an unmirrored "
                                                  "camera above it does: leave it out")
    worst = int(fit.residuals_m.argmax())
    if fit.max_m > max_error_m:
        u, v, x, y = ref[worst]
        raise BadInput(points_path, f"line {worst + 2}", f"({u:g}, {v:g}) px -> ({x:g}, {y:g}) m is {fit.max_m:.2f} m "
                                                         f"off the fit of the others (RMS {fit.rms_m:.2f} m, "
                                                         f"--max-error {max_error_m:g}): mistyped, or a pixel read "
                                                         "off the water?")
    if size is not None:
        outside = np.flatnonzero((ref[:, 0] < -0.5) | (ref[:, 1] < -0.5) | (ref[:, 0] > size[0] - 0.5)
                                 | (ref[:, 1] > size[1] - 0.5))
        if len(outside):
            raise BadInput(points_path, f"line {outside[0] + 2}", f"pixel ({ref[outside[0], 0]:g}, "
                                                                  f"{ref[outside[0], 1]:g}) is outside a "
                                                                  f"{size[0]}x{size[1]} frame (--image-size)")
    doc = {"H": fit.H.tolist(), "rms_m": fit.rms_m, "max_m": fit.max_m, "points": len(ref)}
    if size is not None:
        doc["image_size"] = list(size)
    if mirrored_image:
        doc["mirrored_image"] = True
    from controller.atomic_files import write_text_atomically
    write_text_atomically(out_path, json.dumps(doc, indent=2) + "\n")
    with report_beside(out_path):
        _report(ref, fit, out_path)


def _report(ref, fit, out_path) -> None:
    if len(ref) <= LIST_AT_MOST:
        for k, ((u, v, x, y), r) in enumerate(zip(ref, fit.residuals_m, strict=True), 1):
            click.echo(f"point {k}: ({u:.1f}, {v:.1f}) px -> ({x:.3f}, {y:.3f}) m: error {r:.3f} m")
    click.echo(f"{len(ref)} points: error on the pond RMS {fit.rms_m:.3f} m, worst {fit.max_m:.3f} m "
               f"(point {int(fit.residuals_m.argmax()) + 1})")
    click.echo(f"written: {out_path}")

