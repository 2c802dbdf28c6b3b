"""``fishfarm calibrate chessboard``: stereo calibration from pairs of views of a printed board.

    fishfarm calibrate chessboard --left 'L*.png' --right 'R*.png' --pattern 9x6 --square-mm 25 \
        --out CALIB.json

Pairs are the two globs' matches in sorted order. Writes CALIB.json (P1 = K1[I|0], P2 = K2[R|T],
world = camera 1 frame in mm, plus K1 D1 K2 D2 R T image_size rms_px) and prints a report.
"""
from __future__ import annotations

import glob
import re
from pathlib import Path

import click

from controller.cli.params import Finite
from controller.errors import BadInput


def _pattern(ctx, param, value: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value or "")
    if not m or min(int(m[1]), int(m[2])) < 3:
        raise click.BadParameter(f"{value!r}: expected COLSxROWS of inner corners, each >= 3 (e.g. 9x6)")
    return int(m[1]), int(m[2])


def _files(pattern: str, option: str) -> list[str]:
    files = sorted(glob.glob(pattern))
    if not files:
        raise BadInput(pattern, option, "no files match")
    return files


def _read(path: str):
    import cv2
    import numpy as np

    from controller.image_io import opencv_decode

    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise BadInput(path, None, f"cannot read: {exc.strerror or exc}") from None
    img = opencv_decode(data, path, cv2.IMREAD_GRAYSCALE, "PNG/JPEG") if data.size else None
    if img is None:
        raise BadInput(path, None, "not a readable image (PNG/JPEG expected)")
    return img


def _load_pairs(lefts: list[str], rights: list[str]):
    """Grey images of each pair, all of one size: (images1, images2, (width, height))."""
    images1, images2, size, first = [], [], None, None
    for left, right in zip(lefts, rights, strict=True):
        for path, out in ((left, images1), (right, images2)):
            img = _read(path)
            shape = (img.shape[1], img.shape[0])
            if size is None:
                size, first = shape, path
            elif shape != size:
                raise BadInput(path, None, f"image size {shape[0]}x{shape[1]} differs from "
                                           f"{first}'s {size[0]}x{size[1]}")
            out.append(img)
    return images1, images2, size


def _reasons(pairs, lefts) -> str:
    """'board not found in right: 2 pairs (left03.png, ...)' for each reason a pair went unused."""
    by_reason: dict[str, list[str]] = {}
    for p in pairs:
        if not p.used:
            by_reason.setdefault(p.reason.split(":")[0], []).append(Path(lefts[p.index]).name)
    return "; ".join(f"{reason}: {len(names)} pair(s), e.g. {names[0]}"
                     for reason, names in by_reason.items())


def _report(result, lefts, rights, out: str) -> None:
    pairs = result.pairs
    used = [p for p in pairs if p.used]
    click.echo(f"pairs: {len(pairs)} given, {len(used)} used, {len(pairs) - len(used)} rejected")
    for p in pairs:
        rms = "" if p.rms_px is None or "RMS" in p.reason else f"  reprojection RMS {p.rms_px:.3f} px"
        click.echo(f"  {Path(lefts[p.index]).name} + {Path(rights[p.index]).name}: {p.reason}{rms}")
    click.echo(f"RMS reprojection error: {result.rms_px:.3f} px")
    click.echo(f"mean epipolar error: {result.epipolar_px:.3f} px "
               "(OpenCV stereo_calib definition: per corner, distance to its line in both images, summed)")
    baseline = float((result.calibration.T ** 2).sum() ** 0.5)
    click.echo(f"baseline: {result.baseline_squares:.3f} squares ({baseline:.1f} mm)")
    from controller.cli.calibrate_import import warn_folds
    warn_folds(result.calibration)
    click.echo(f"wrote {out}")


@click.command()
@click.option("--left", "left_glob", required=True, help="Glob of camera 1 (left) images, e.g. 'L*.png'.")
@click.option("--right", "right_glob", required=True, help="Glob of camera 2 (right) images.")
@click.option("--pattern", default="9x6", show_default=True, callback=_pattern,
              help="Inner corners of the board, COLSxROWS.")
@click.option("--square-mm", type=Finite(min=0, min_open=True), required=True,
              help="Side of one square, mm.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="CALIB.json to write.")
def chessboard(left_glob, right_glob, pattern, square_mm, out):
    """Stereo calibration from pairs of chessboard views (pairs by sorted file name)."""
    from controller.cli.calib_io import save_calibration
    from controller.cli.output_paths import check_outputs, report_beside
    from vision.calib_file import CalibrationError, calibration_from_json
    from vision.chessboard import BadFit, NotEnoughPairs, calibrate_pairs, find_corners

    lefts, rights = _files(left_glob, "--left"), _files(right_glob, "--right")
    check_outputs({"--out": out}, lefts + rights)
    if len(lefts) != len(rights):
        raise BadInput(right_glob, "--right", f"{len(rights)} files, but --left matches {len(lefts)}: "
                                              "images pair up in sorted order")
    images1, images2, size = _load_pairs(lefts, rights)
    corners1 = [find_corners(img, pattern) for img in images1]
    corners2 = [find_corners(img, pattern) for img in images2]
    where = f"{left_glob} + {right_glob}"
    if not any(c is not None for c in corners1 + corners2):
        raise BadInput(where, f"--pattern {pattern[0]}x{pattern[1]}",
                       f"board not found in any of the {len(lefts)} pairs (inner corners, COLSxROWS)")
    try:
        result = calibrate_pairs(corners1, corners2, size, pattern, square_mm)
    except NotEnoughPairs as exc:
        reasons = _reasons(exc.pairs, lefts)
        raise BadInput(where, None, f"{exc} ({reasons})" if reasons else str(exc)) from None
    except BadFit as exc:
        raise BadInput(where, None, str(exc)) from None
    calib = result.calibration
    calib.extra = {"method": "chessboard", "pattern": list(pattern), "square_mm": square_mm,
                   "epipolar_px": result.epipolar_px,
                   "pairs_used": sum(p.used for p in result.pairs), "pairs_given": len(result.pairs)}
    try:        # what every command checks on reading it: a file it writes must be one they take
        calibration_from_json(calib.to_json())
    except CalibrationError as exc:
        same = " (are --left and --right the same camera's views?)" if exc.field in ("P2", "T") else ""
        raise BadInput(where, exc.field, f"{exc.fault}{same}") from None
    save_calibration(calib, out)
    with report_beside(out):
        _report(result, lefts, rights, out)
