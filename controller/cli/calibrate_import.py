"""``fishfarm calibrate import``: a stereo calibration made by another tool, into CALIB.json.

    fishfarm calibrate import --in FILE [--in FILE2] --out CALIB.json [--format auto|opencv|stereomorph|p34]
        [--units mm|cm|m|in | --square-mm MM] [--image-size WxH] [--pixel-origin zero|corner|one] [--y-up]

Formats (``auto`` decides from the content, not the name; each input is read whole, once, so pipes
such as /dev/stdin or a shell's <(zcat f) work):
- opencv: cv2.FileStorage YAML or XML from stereoCalibrate; several files are merged (OpenCV's
  stereo_calib sample writes intrinsics.yml and extrinsics.yml; a field in both must have one
  value). Names are matched without case or "_" (controller/cli/calib_opencv_file.py), the same
  words for K and D: K1 M1 cameraMatrix1 camera_matrix_left left_camera_matrix ...; D1 distCoeffs1
  distortion_coefficients_left ...; cameras counted from 0 (camera_matrix_0) when the file does; R;
  T; image_width + image_height or imageSize / image_size [w, h]. Refused: two names of one field in
  a file; a key that looks like distortion but names neither D when a D is missing; a fisheye
  (equidistant, Kannala-Brandt) model named anywhere (distortion_model: fisheye): its k1..k4 are not
  the pinhole's k1 k2 p1 p2, and 4 coefficients with no model named are the pinhole's. Rectified
  P1/P2 in such files are ignored: they are for rectified images, not the camera's own pixels.
  gzip'd FileStorage files are unpacked, whatever their name. A JSON object with K1/K2/R/T is
  OpenCV's too where it has no P1/P2, or has stereoRectify's Q, R1 or R2 beside them; with P1/P2
  and none of those it is CALIB.json's own form (p34). T in board squares (OpenCV's stereo_calib
  sample): ``--square-mm`` the square's side.
- stereomorph: StereoMorph's own calibration file (``calibrateCameras``' calibration.txt: its
  cal.coeff, img.size and the unit of sq.size; controller/cli/stereomorph_file.py), or a table of
  11 DLT coefficients per camera, one column per camera (StereoMorph's cal_coeffs), with or
  without a header row and row names, separated by spaces, tabs, commas or semicolons; 2 rows of
  11 are read as one row per camera.
- p34: two 3x4 matrices, P1 then P2 row by row (24 numbers, any separators, as 6 rows of 4, 2 rows
  of 12 or one row of 24; other layouts are refused naming theirs); or JSON of CALIB.json's form
  (P1, P2 and any of K1 D1 K2 D2 R T image_size rms_px, other fields kept as they are): fishfarm's
  own output round-trips. Another tool's name for one of its fields (distCoeffs1) is refused.
An image size (the file's or --image-size) must contain both principal points.
Bad input exits 2 with one line naming the file, the field and the fault (controller.errors.BadInput).
"""
from __future__ import annotations

import gzip
import math
import re
import zlib
from dataclasses import dataclass
from pathlib import Path

import click
import numpy as np

from controller.cli.calib_opencv_file import OPENCV_NAMES, opencv_fields, opencv_json, opencv_size
from controller.cli.calib_tables import dlt_table, numbers_table, p34_json, p34_text, strip_row_index
from controller.cli.params import image_size_option
from controller.cli.stereomorph_file import StereoMorphCalibration, is_stereomorph_file, read_stereomorph
from controller.errors import BadInput
from vision import calib_import
from vision.calib_import import UNITS_MM

FORMATS = ("auto", "opencv", "stereomorph", "p34")
GZIP_MAGIC = b"\x1f\x8b"
PLAUSIBLE_BASELINE_MM = (20.0, 3000.0)     # outside: most likely a wrong --units (warned, not refused)


def _square_mm_option(ctx, param, value):
    # FloatRange passes nan (no comparison holds) and inf: neither is a board's square
    if value is not None and not math.isfinite(value):
        raise click.BadParameter(f"{value}: expected a finite number of mm > 0")
    return value


def _read_input(path: str) -> tuple[str, bool]:
    """The input's text and whether it was gzip'd. Read whole, once: a pipe (/dev/stdin, a shell's
    <(zcat f)) cannot be read twice, so gzip is sniffed in these bytes, by its magic whatever the name."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise BadInput(path, None, "no such file") from None
    except OSError as exc:
        raise BadInput(path, None, f"cannot read: {exc.strerror or exc}") from None
    gzipped = data[:2] == GZIP_MAGIC
    if gzipped:
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as exc:
            raise BadInput(path, None, f"gzip'd, but cannot be unpacked: {exc}") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise BadInput(path, None, "not a text file") from None
    if not text.strip():
        raise BadInput(path, None, "empty")
    return text, gzipped


# the first line of a YAML mapping (FileStorage reads YAML without its '%YAML' header)
_YAML_KEY = re.compile(r"[A-Za-z_][\w.\-]*\s*:(\s|$)")


def _detect(path: str, text: str) -> str:
    """The format by content (a name says little: StereoMorph's file saved as .xml, a table as .yml)."""
    head = text.lstrip()[:64]
    if is_stereomorph_file(text):
        return "stereomorph"
    if head.startswith(("%YAML", "<?xml", "<opencv_storage")):
        return "opencv"
    if head.startswith("{"):
        return "opencv" if opencv_json(text) else "p34"
    if head.startswith("["):
        raise BadInput(path, None, "a JSON array: expected a JSON object (OpenCV's names, or P1 and P2)")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith(("#", "---"))]
    return "opencv" if lines and _YAML_KEY.match(lines[0]) else "table"


def _stereomorph(path: str, text: str, units: str | None, square_mm: float | None) -> StereoMorphCalibration:
    """StereoMorph's calibration file, whose sq.size names its unit: another --units is refused."""
    stereomorph = read_stereomorph(path, text, tuple(UNITS_MM))
    if units and stereomorph.units and units != stereomorph.units:
        raise BadInput(path, "--units", f"{units}, where the file's sq.size says {stereomorph.units}")
    if square_mm is not None and stereomorph.units:
        raise BadInput(path, "--square-mm", f"the file's sq.size gives its unit ({stereomorph.units})")
    return stereomorph


@dataclass
class _Job:
    """One import's inputs, read and decided: what the builders below need."""
    paths: list[str]
    texts: dict[str, str]
    stereomorph: StereoMorphCalibration | None
    image_size: tuple[int, int] | None         # --image-size, or StereoMorph's img.size
    mm: float                                  # mm per world unit
    extra: dict
    pixel_origin: str
    y_up: bool

    def pixel(self, size=None):
        size = size or self.image_size
        return calib_import.pixel_transform(self.pixel_origin, self.y_up, size[1] if size else None)


def _from_opencv(job: _Job, kind: str):
    found, source = opencv_fields([(p, job.texts[p]) for p in job.paths])
    missing = [f for f in ("K1", "K2", "R", "T") if f not in found]
    if missing:
        raise BadInput(", ".join(job.paths), missing[0],
                       f"missing (looked for {', '.join(OPENCV_NAMES[missing[0]][:4])}, ...)")
    return calib_import.from_opencv(found["K1"], found.get("D1"), found["K2"], found.get("D2"), found["R"],
                                    found["T"], mm_per_unit=job.mm,
                                    image_size=job.image_size or opencv_size(found, source), extra=job.extra)


def _from_json(job: _Job, kind: str):
    first = job.paths[0]
    data = p34_json(first, job.texts[first])
    size = job.image_size or data.get("image_size")
    has_k = [k for k in ("K1", "K2") if data.get(k) is not None]
    if has_k and (job.pixel_origin != "zero" or job.y_up):
        raise BadInput(first, "--pixel-origin/--y-up", f"the file has {has_k[0]}: its K and D are in "
                                                       "OpenCV's pixel convention already")
    return calib_import.from_calibration(data, mm_per_unit=job.mm, pixel=job.pixel(size), image_size=size,
                                         extra=job.extra)


def _from_stereomorph(job: _Job, kind: str):
    return calib_import.from_dlt11(job.stereomorph.coefficients, mm_per_unit=job.mm, pixel=job.pixel(),
                                   image_size=job.image_size, extra=job.extra)


def _from_table(job: _Job, kind: str):
    first = job.paths[0]
    rows = strip_row_index(numbers_table(first, job.texts[first]))
    if kind == "table":                 # auto: the count of numbers tells
        n = sum(len(r) for r in rows)
        kind = {22: "stereomorph", 24: "p34"}.get(n)
        if kind is None:
            raise BadInput(first, None, f"{n} numbers: expected 22 (DLT-11 x 2 cameras, StereoMorph) "
                                        "or 24 (two 3x4 matrices); give --format")
        job.extra["format"] = kind
    if kind == "stereomorph":
        return calib_import.from_dlt11(dlt_table(first, rows), mm_per_unit=job.mm, pixel=job.pixel(),
                                       image_size=job.image_size, extra=job.extra)
    P1, P2 = p34_text(first, rows)
    return calib_import.from_projections(P1, P2, mm_per_unit=job.mm, pixel=job.pixel(), image_size=job.image_size,
                                         extra=job.extra)


def _report(calib, fmt: str, paths, out: str) -> None:
    from vision.calib_file import principal_point
    from vision.triangulation import camera_centre

    baseline = float(np.linalg.norm(camera_centre(calib.P1) - camera_centre(calib.P2)))
    click.echo(f"read {', '.join(paths)} as {fmt}")
    click.echo(f"baseline: {baseline:.1f} mm")
    if not PLAUSIBLE_BASELINE_MM[0] <= baseline <= PLAUSIBLE_BASELINE_MM[1]:
        click.echo(f"warning: a stereo rig is seldom {baseline:.1f} mm wide: is the file in --units "
                   f"{'m or cm' if baseline < PLAUSIBLE_BASELINE_MM[0] else 'mm or cm'}?", err=True)
    for cam in (1, 2):
        u, v = principal_point(calib, cam)
        click.echo(f"camera {cam}: principal point ({u:.1f}, {v:.1f}) px")
    size = "not given (surveys accept frames that contain both principal points)" if calib.image_size is None \
        else f"{calib.image_size[0]}x{calib.image_size[1]}"
    click.echo(f"image size: {size}")
    click.echo(f"distortion: {'D1/D2 kept' if calib.has_distortion else 'none'}")
    warn_folds(calib)
    click.echo(f"wrote {out}")


def warn_folds(calib) -> None:
    """A lens model that folds back inside the image (fitted to a board that never reached its
    corners): said, as the pixels beyond are not measured (triangulate writes them nan, surveys
    drop what lies there)."""
    from vision.triangulation import reach_in_image
    if calib.image_size is None or not calib.has_distortion:
        return
    for cam, K, D in ((1, calib.K1, calib.D1), (2, calib.K2, calib.D2)):
        folds = reach_in_image(K, D, calib.image_size)
        if folds is not None:
            click.echo(f"warning: D{cam}: the lens model folds back {folds[0]:.0f} px from the principal point, inside "
                       f"the {calib.image_size[0]}x{calib.image_size[1]} image (its farthest corner is "
                       f"{folds[1]:.0f} px away): pixels beyond have no ray and are not measured; a calibration "
                       f"with the board in the corners reaches them", err=True)


@click.command("import")
@click.option("--in", "inputs", multiple=True, required=True, metavar="FILE",
              help="Calibration file; repeat for OpenCV files split in two (intrinsics + extrinsics).")
@click.option("--out", required=True, type=click.Path(dir_okay=False), metavar="CALIB.json")
@click.option("--format", "fmt", type=click.Choice(FORMATS), default="auto", show_default=True)
@click.option("--units", type=click.Choice(list(UNITS_MM)), default=None,
              help="World unit of the file: OpenCV's T (the board's square unit), DLT and 3x4 worlds "
                   "[default: a StereoMorph calibration file's square unit, else mm].")
@click.option("--square-mm", type=click.FloatRange(min=0, min_open=True), default=None, metavar="MM",
              callback=_square_mm_option,
              help="The file's world unit is a calibration board's square this many mm wide (OpenCV's "
                   "stereo_calib sample, squareSize 1, gives T in squares); instead of --units.")
@click.option("--image-size", callback=image_size_option, metavar="WxH",
              help="Frame size the calibration was made for (overrides the file's).")
@click.option("--pixel-origin", type=click.Choice(["zero", "corner", "one"]), default="zero", show_default=True,
              help="stereomorph/p34: top-left pixel centre at (0,0) as OpenCV, (0.5,0.5), or (1,1).")
@click.option("--y-up", is_flag=True, help="stereomorph/p34: v grows upwards (needs the image size).")
def import_(inputs, out, fmt, units, square_mm, image_size, pixel_origin, y_up):
    """Import a stereo calibration from OpenCV, StereoMorph (DLT-11) or a plain 3x4 pair."""
    from controller.cli.calib_io import save_calibration
    from controller.cli.output_paths import check_outputs, report_beside
    from vision.calib_file import CalibrationError

    paths = list(inputs)
    size_given = image_size is not None
    check_outputs({"--out": out}, paths)
    first = paths[0]
    if square_mm is not None and units is not None:
        raise BadInput(first, "--square-mm", "give the world unit once: --units or --square-mm")
    texts = {path: _read_input(path) for path in dict.fromkeys(paths)}
    text, gzipped = texts[first]
    if gzipped and fmt not in ("auto", "opencv"):
        raise BadInput(first, "--format", f"{fmt}, but the file is gzip'd: only OpenCV FileStorage files "
                                          "are read compressed")
    kind = "opencv" if gzipped else _detect(first, text) if fmt == "auto" else fmt
    stereomorph = None
    if kind in ("table", "stereomorph", "p34") and is_stereomorph_file(text):
        if kind == "p34":
            raise BadInput(first, "--format", "p34, but this is StereoMorph's calibration file: "
                                              "--format stereomorph or auto")
        stereomorph, kind = _stereomorph(first, text, units, square_mm), "stereomorph"
        units = units or stereomorph.units
        image_size = image_size or stereomorph.image_size
    units = units or "mm"
    if kind != "opencv" and len(paths) > 1:
        raise BadInput(paths[1], "--in", "only OpenCV files may be given in parts")
    if kind == "opencv" and (pixel_origin != "zero" or y_up):
        raise BadInput(first, "--pixel-origin/--y-up", "OpenCV files are in OpenCV's pixel convention already")
    mm = UNITS_MM[units] if square_mm is None else square_mm
    extra = {"method": "import", "format": kind if kind != "table" else "auto", "source": [Path(p).name for p in paths],
             "units": units if square_mm is None else f"square of {square_mm:g} mm"}
    job = _Job(paths, {p: t for p, (t, _) in texts.items()}, stereomorph, image_size, mm, extra, pixel_origin, y_up)
    build = _from_opencv if kind == "opencv" else _from_json if kind == "p34" and text.lstrip().startswith("{") \
        else _from_stereomorph if stereomorph is not None else _from_table
    where = " + ".join(paths) if kind == "opencv" else first
    try:
        calib = build(job, kind)
    except CalibrationError as exc:
        if exc.field == "image_size" and y_up and exc.fault.startswith("needed"):   # pixel_transform: no height
            raise BadInput(where, "--y-up", "needs the image height: give --image-size WxH") from None
        field = "--image-size" if exc.field == "image_size" and size_given else exc.field
        raise BadInput(where, field, exc.fault) from None
    save_calibration(calib, out)
    with report_beside(out):
        _report(calib, extra["format"], paths, out)
