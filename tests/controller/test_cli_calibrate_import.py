"""``fishfarm calibrate import``: files written here as each tool writes them, read back into
CALIB.json, checked by triangulating a known rig's pixels; and bad files, one line, exit 2."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from controller.cli import main
from controller.cli.calib_io import load_calibration
from devices.sim.stereo_rig import convergent_rig
from vision.triangulation import triangulate_calibrated

REPO = Path(__file__).resolve().parents[2]
RIG = convergent_rig(distortion=np.array([-0.1, 0.04, 0.0008, -0.0004, 0.0]))
R = RIG.R2 @ RIG.R1.T
T = RIG.t2 - R @ RIG.t1                                   # mm
WORLD = np.random.default_rng(2).uniform([0, 0, 0], [400, 400, 250], (40, 3))
PLAIN = convergent_rig()                                  # no distortion: for the DLT and 3x4 files


def run(*args: str) -> tuple[int, str, str]:
    """The command in-process, as ``fishfarm calibrate import ARGS``: exit code, stdout, stderr."""
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["calibrate", "import", *args])
    return code, out.getvalue(), err.getvalue()


def assert_bad(args, *words):
    code, _, err = run(*args)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in lines[0], lines[0]


def write_opencv(path: Path, names: dict[str, str], *, units_per_mm: float = 1.0, size: str = "wh",
                 rectified: bool = False) -> None:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for field, value in (("K1", RIG.K1), ("D1", RIG.D1.reshape(1, 5)), ("K2", RIG.K2),
                         ("D2", RIG.D2.reshape(1, 5)), ("R", R), ("T", (T * units_per_mm).reshape(3, 1))):
        if field in names:
            fs.write(names[field], value)
    if size == "wh":
        fs.write("image_width", 1280)
        fs.write("image_height", 960)
    elif size == "seq":
        fs.startWriteStruct("imageSize", cv2.FileNode_SEQ)
        for v in (1280, 960):
            fs.write("", v)
        fs.endWriteStruct()
    if rectified:               # stereoRectify's outputs: must not be taken for the camera's P1/P2
        fs.write("P1", np.eye(3, 4) * 7)
        fs.write("P2", np.eye(3, 4) * 9)
    fs.release()


def assert_reconstructs(out: Path, world_mm: np.ndarray, rig=RIG, atol=0.05) -> None:
    calib = load_calibration(out)
    p1, p2 = rig.project(WORLD)
    X, _ = triangulate_calibrated(calib, p1, p2)
    np.testing.assert_allclose(X, world_mm, atol=atol)


CAMERA1 = WORLD @ RIG.R1.T + RIG.t1                        # OpenCV's world: camera 1's frame, mm
M_NAMES = {"K1": "M1", "D1": "D1", "K2": "M2", "D2": "D2", "R": "R", "T": "T"}
K_NAMES = {"K1": "K1", "D1": "D1", "K2": "K2", "D2": "D2", "R": "R", "T": "T"}
LONG_NAMES = {"K1": "cameraMatrix1", "D1": "distCoeffs1", "K2": "cameraMatrix2", "D2": "distCoeffs2",
              "R": "R", "T": "T"}


@pytest.mark.parametrize("ext", ["yml", "xml", "json"])   # FileStorage writes JSON too
@pytest.mark.parametrize("names,size", [(M_NAMES, "wh"), (K_NAMES, "seq"), (LONG_NAMES, None)])
def test_opencv_files_of_each_naming(tmp_path, ext, names, size):
    src = tmp_path / f"stereo.{ext}"
    write_opencv(src, names, size=size, rectified=True)
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0, err
    assert "as opencv" in stdout and "baseline: 400.0 mm" in stdout and err == ""
    calib = load_calibration(out)
    assert calib.image_size == (None if size is None else (1280, 960))
    np.testing.assert_allclose(calib.T, T, atol=1e-9)
    assert calib.extra["method"] == "import" and calib.extra["units"] == "mm"
    assert_reconstructs(out, CAMERA1)


def test_a_json_file_written_by_hand_with_opencvs_names_and_rows_of_numbers(tmp_path):
    src = tmp_path / "rig.json"
    src.write_text(json.dumps({"cameraMatrix1": RIG.K1.tolist(), "distCoeffs1": RIG.D1.tolist(),
                               "cameraMatrix2": RIG.K2.tolist(), "distCoeffs2": RIG.D2.tolist(),
                               "R": R.tolist(), "T": T.tolist(), "imageSize": [1280, 960]}))
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0, err
    assert "as opencv" in stdout
    assert load_calibration(out).image_size == (1280, 960)
    assert_reconstructs(out, CAMERA1)
    ragged = tmp_path / "ragged.json"
    ragged.write_text(json.dumps({"K1": [[1, 0, 640], [0, 1]], "K2": RIG.K2.tolist(), "R": R.tolist(),
                                  "T": T.tolist()}))
    assert_bad(["--in", str(ragged), "--out", str(out)], "ragged.json", "K1", "not a matrix or a list of numbers")


@pytest.mark.parametrize("units", ["cm", "m"])
def test_opencv_translation_in_the_boards_unit(tmp_path, units):
    per_mm = {"cm": 0.1, "m": 0.001}[units]
    src = tmp_path / "stereo.yaml"
    write_opencv(src, M_NAMES, units_per_mm=per_mm)
    out = tmp_path / "CALIB.json"
    assert run("--in", str(src), "--out", str(out), "--units", units)[0] == 0
    assert_reconstructs(out, CAMERA1)
    code, _, err = run("--in", str(src), "--out", str(tmp_path / "wrong.json"))     # mm assumed: wrong scale
    assert code == 0 and ("warning: a stereo rig is seldom 0.4 mm wide" in err) == (units == "m")
    assert np.linalg.norm(load_calibration(tmp_path / "wrong.json").T) == pytest.approx(400.0 * per_mm)


def test_opencv_intrinsics_and_extrinsics_in_two_files(tmp_path):
    """OpenCV's stereo_calib sample: intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml (R T R1 R2 P1 P2 Q)."""
    intr, extr = tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml"
    write_opencv(intr, {k: M_NAMES[k] for k in ("K1", "D1", "K2", "D2")}, size=None)
    write_opencv(extr, {"R": "R", "T": "T"}, size=None, rectified=True)
    out = tmp_path / "CALIB.json"
    code, _, err = run("--in", str(intr), "--in", str(extr), "--out", str(out), "--image-size", "1280x960")
    assert code == 0, err
    assert load_calibration(out).image_size == (1280, 960)
    assert_reconstructs(out, CAMERA1)
    assert_bad(["--in", str(intr), "--out", str(out)], "intrinsics.yml", "R", "missing")


@pytest.mark.parametrize("size", ["100001x960", "99999999999999999999x960", "1280x0"])
def test_an_image_size_no_camera_has_is_refused_by_its_option(tmp_path, size):
    """Past int64 it reached numpy ("internal error"); past 100000 px the file could not be read back."""
    src = tmp_path / "stereo.yml"
    write_opencv(src, M_NAMES)
    out = tmp_path / "CALIB.json"
    assert_bad(["--in", str(src), "--out", str(out), "--image-size", size], "--image-size", "1..100000")
    assert not out.exists()


def test_a_json_dump_of_stereo_calibrate_and_stereo_rectify_is_read_for_its_cameras(tmp_path):
    """json.dump of stereoCalibrate + stereoRectify (K D R T R1 R2 P1 P2 Q): the P1/P2 are the
    rectified cameras', not these pixels'; without stereoRectify's products P1/P2 are CALIB.json's."""
    size = (1280, 960)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(RIG.K1, RIG.D1, RIG.K2, RIG.D2, size, R, T.reshape(3, 1))
    doc = {"K1": RIG.K1.tolist(), "D1": RIG.D1.tolist(), "K2": RIG.K2.tolist(), "D2": RIG.D2.tolist(),
           "R": R.tolist(), "T": T.tolist(), "P1": P1.tolist(), "P2": P2.tolist()}
    out = tmp_path / "CALIB.json"
    for extra in ({"R1": R1.tolist()}, {"R2": R2.tolist()}, {"Q": Q.tolist()}):
        src = tmp_path / "rectified.json"
        src.write_text(json.dumps(doc | extra))
        code, stdout, err = run("--in", str(src), "--out", str(out))
        assert code == 0 and "as opencv" in stdout, (extra.keys(), err)
        assert_reconstructs(out, CAMERA1)
    ours = tmp_path / "ours.json"                 # CALIB.json's own form: P1/P2 with K, D, R, T
    ours.write_text(json.dumps({"P1": PLAIN.P1.tolist(), "P2": PLAIN.P2.tolist(), "K1": PLAIN.K1.tolist(),
                                "K2": PLAIN.K2.tolist(), "R": R.tolist(), "T": T.tolist()}))
    code, stdout, err = run("--in", str(ours), "--out", str(out))
    assert code == 0 and "as p34" in stdout, err
    assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-6)


def test_a_gzipped_filestorage_file_is_read_as_it_is(tmp_path):
    import gzip
    plain = tmp_path / "stereo.yml"
    write_opencv(plain, M_NAMES)
    packed = tmp_path / "stereo.yml.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes()))
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(packed), "--out", str(out))
    assert code == 0 and "as opencv" in stdout, err
    assert_reconstructs(out, CAMERA1)
    assert_bad(["--in", str(packed), "--out", str(tmp_path / "x.json"), "--format", "p34"],
               "stereo.yml.gz", "--format", "gzip")


@pytest.mark.parametrize("square_mm", [1.0, 25.0, 52.45])
def test_opencv_translation_in_board_squares_with_the_square_s_size(tmp_path, square_mm):
    """OpenCV's stereo_calib sample calibrates with squareSize 1: T in squares."""
    src = tmp_path / "extrinsics.yml"
    write_opencv(src, M_NAMES, units_per_mm=1.0 / square_mm)
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out), "--square-mm", f"{square_mm}")
    assert code == 0 and "baseline: 400.0 mm" in stdout, err
    assert load_calibration(out).extra["units"] == f"square of {square_mm:g} mm"
    assert_reconstructs(out, CAMERA1)
    assert_bad(["--in", str(src), "--out", str(out), "--square-mm", "25", "--units", "cm"], "--square-mm",
               "--units")


@pytest.mark.parametrize("size, fault", [("[1280.5, 960]", "1280.5"), ("[1e30, 960]", "1..100000"),
                                         ("[0, 960]", "1..100000"), ("[true, 960]", "image_size")])
def test_an_image_size_that_is_not_whole_pixels_is_refused(tmp_path, size, fault):
    src = tmp_path / "rig.json"
    cams = ", ".join(f'"{k}": {json.dumps(v.tolist())}' for k, v in (("K1", RIG.K1), ("K2", RIG.K2), ("R", R),
                                                                     ("T", T)))
    src.write_text(f'{{{cams}, "imageSize": {size}}}')
    if "true" not in size:                      # (FileStorage reads JSON's true as 1)
        assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "rig.json", "image_size", fault)
    p34 = tmp_path / "p.json"
    p34.write_text(f'{{"P1": {json.dumps(PLAIN.P1.tolist())}, "P2": {json.dumps(PLAIN.P2.tolist())}, '
                   f'"image_size": {size}}}')
    assert_bad(["--in", str(p34), "--out", str(tmp_path / "o.json")], "p.json", "image_size")


def _dlt_columns(units_per_mm: float = 1.0, pixel_shift: float = 0.0) -> np.ndarray:
    """StereoMorph's cal_coeffs: 11 rows x 2 cameras, the world in its unit, pixels shifted."""
    to_unit = np.diag([1 / units_per_mm] * 3 + [1.0])
    shift = np.array([[1.0, 0, pixel_shift], [0, 1.0, pixel_shift], [0, 0, 1.0]])
    cols = []
    for P in (PLAIN.P1, PLAIN.P2):
        Q = shift @ P @ to_unit
        cols.append((Q / Q[2, 3]).reshape(-1)[:11])
    return np.array(cols).T


def _write_table(path: Path, table: np.ndarray, style: str) -> None:
    if style == "tabs":                       # as StereoMorph's example cal_coeffs.txt
        text = "\n".join("\t".join(f"{v:.10g}" for v in row) for row in table)
    elif style == "r-write.table":            # R's write.table(cal.coeff): quoted header and row names
        text = '"V1" "V2"\n' + "\n".join(f'"{i + 1}" {a:.12g} {b:.12g}' for i, (a, b) in enumerate(table))
    elif style == "csv-header":
        text = "cam1,cam2\n" + "\n".join(f"{a:.12g},{b:.12g}" for a, b in table)
    elif style == "row-index":
        text = "\n".join(f"{i + 1} {a:.12g} {b:.12g}" for i, (a, b) in enumerate(table))
    else:                                     # one row per camera
        text = "\n".join(" ".join(f"{v:.12g}" for v in col) for col in table.T)
    path.write_text(text + "\n", encoding="utf-8")


@pytest.mark.parametrize("style", ["tabs", "r-write.table", "csv-header", "row-index", "transposed"])
def test_stereomorph_dlt_coefficients(tmp_path, style):
    src = tmp_path / "cal_coeffs.txt"
    _write_table(src, _dlt_columns(units_per_mm=0.1), style)            # calibrated in cm
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out), "--units", "cm")
    assert code == 0, err
    assert "as stereomorph" in stdout
    assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-4)


def test_stereomorph_one_based_pixels(tmp_path):
    src = tmp_path / "cal_coeffs.txt"
    _write_table(src, _dlt_columns(pixel_shift=1.0), "tabs")
    out = tmp_path / "CALIB.json"
    assert run("--in", str(src), "--out", str(out), "--format", "stereomorph", "--pixel-origin", "one")[0] == 0
    assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-4)


def _xml4r_matrix(name: str, values, cols=None, rows=None) -> str:
    """An R matrix as StereoMorph's list2XML4R writes it: tab-indented, names optional."""
    values = np.asarray(values)
    head = (f"\t<{name} type=matrix rownames={'TRUE' if rows else 'FALSE'} colnames={'TRUE' if cols else 'FALSE'} "
            f"nrow={values.shape[0]} ncol={values.shape[1]} as.numeric=TRUE >")
    lines = ["\t\t" + ("\t" if rows else "") + "\t".join(cols)] if cols else []
    for i, row in enumerate(values):
        lines.append("\t\t" + (f"{rows[i]}\t" if rows else "") + "\t".join(repr(float(v)) for v in row))
    return "\n".join([head, *lines, f"\t</{name}>"])


def write_stereomorph_calibration(path: Path, coeff: np.ndarray, *, square: str = "2.5 cm",
                                  sizes=((1280, 960), (1280, 960)), extra: str = "") -> None:
    """StereoMorph's calibrateCameras output (calibration.txt): XML4R elements, most of them of no
    use to a DLT import (corner counts, file names, errors), the coefficients among them."""
    views = ["cam_L", "cam_R", "cam_T"][:coeff.shape[1]]
    path.write_text("\n".join([
        "<calibration type=list>",
        "\t<img.type type=vector names=FALSE length=1 as.numeric=FALSE >video</img.type>",
        _xml4r_matrix("img.size", sizes, cols=["w", "h"], rows=views[:len(sizes)]),
        "\t<img.fpaths type=vector names=FALSE length=2 as.numeric=FALSE >",
        "\t\tcal/cam_L.mp4", "\t\tcal/cam_R.mp4", "\t</img.fpaths>",
        f"\t<sq.size type=vector names=FALSE length=1 as.numeric=FALSE >{square}</sq.size>",
        "\t<nx type=vector names=FALSE length=1 as.numeric=TRUE >9</nx>",
        _xml4r_matrix("cal.coeff", coeff, cols=views),
        "\t<mean.reconstruct.rmse type=vector names=FALSE length=1 as.numeric=TRUE >0.84</mean.reconstruct.rmse>",
        "\t<coefficient.rmse type=vector names=FALSE length=2 as.numeric=TRUE >", "\t\t1.7", "\t\t1.4",
        "\t</coefficient.rmse>", extra, "</calibration>", ""]), encoding="utf-8")


@pytest.mark.parametrize("square, units_per_mm", [("2.5 cm", 0.1), ("52.45 mm", 1.0), ("0.03 m", 0.001)])
def test_stereomorphs_own_calibration_file_with_its_unit_and_image_size(tmp_path, square, units_per_mm):
    src = tmp_path / "calibration.txt"
    write_stereomorph_calibration(src, _dlt_columns(units_per_mm=units_per_mm), square=square)
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0, err
    assert "as stereomorph" in stdout and "image size: 1280x960" in stdout
    assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-4)              # the square's unit: the world's
    saved = json.loads(out.read_text())
    assert saved["image_size"] == [1280, 960] and saved["units"] == square.split()[1]
    # the same unit given: taken; another: refused (the file says what it is)
    assert run("--in", str(src), "--out", str(out), "--units", square.split()[1])[0] == 0
    other = "in" if square.split()[1] != "in" else "mm"
    assert_bad(["--in", str(src), "--out", str(out), "--units", other], "calibration.txt", "--units",
               f"sq.size says {square.split()[1]}")


@pytest.mark.parametrize("change, field, fault", [
    (dict(extra="\t<undistort.params type=matrix rownames=FALSE colnames=FALSE nrow=1 ncol=1 as.numeric=TRUE >"
                 "\n\t\t0.1\n\t</undistort.params>"), "undistort.params", "undistort = FALSE"),
    (dict(sizes=((1280, 960), (1920, 1080))), "img.size", "the views differ (cam_L 1280x960, cam_R 1920x1080)"),
    (dict(square="3 ft"), "sq.size", "unit 'ft' is not one of"),
    (dict(coeff3=True), "cal.coeff", "3 views (cam_L, cam_R, cam_T)"),
    (dict(short=True), "cal.coeff", "10 rows: expected the 11 DLT coefficients"),
    (dict(nan=True), "cal.coeff", "finite"),
])
def test_a_stereomorph_calibration_file_it_cannot_use_is_refused_by_field(tmp_path, change, field, fault):
    coeff = _dlt_columns()
    if change.pop("coeff3", False):
        coeff = np.column_stack([coeff, coeff[:, 0]])
    if change.pop("short", False):
        coeff = coeff[:10]
    if change.pop("nan", False):
        coeff = coeff.copy()
        coeff[3, 1] = np.nan
    src = tmp_path / "calibration.txt"
    write_stereomorph_calibration(src, coeff, **change)
    out = tmp_path / "CALIB.json"
    assert_bad(["--in", str(src), "--out", str(out)], "calibration.txt", field, fault)
    assert not out.exists()


def test_stereomorphs_calibration_file_read_as_another_format_names_it(tmp_path):
    src = tmp_path / "calibration.txt"
    write_stereomorph_calibration(src, _dlt_columns())
    assert_bad(["--in", str(src), "--out", str(tmp_path / "c.json"), "--format", "p34"], "calibration.txt",
               "--format", "StereoMorph's calibration file")
    assert run("--in", str(src), "--out", str(tmp_path / "c.json"), "--format", "stereomorph")[0] == 0


def test_a_stereomorph_calibration_not_finished_names_what_is_missing(tmp_path):
    src = tmp_path / "calibration.txt"
    src.write_text("<calibration type=list>\n\t<nx type=vector names=FALSE length=1 as.numeric=TRUE >9</nx>\n"
                   "</calibration>\n", encoding="utf-8")
    assert_bad(["--in", str(src), "--out", str(tmp_path / "c.json")], "calibration.txt", "cal.coeff", "missing")


@pytest.mark.parametrize("style", ["text", "json"])
def test_plain_3x4_pair(tmp_path, style):
    if style == "text":
        src = tmp_path / "P.txt"
        src.write_text("# P1\n" + "\n".join(", ".join(f"{v:.15g}" for v in row) for row in PLAIN.P1)
                       + "\n# P2\n" + "\n".join(" ".join(f"{v:.15g}" for v in row) for row in PLAIN.P2) + "\n")
    else:
        src = tmp_path / "P.json"
        src.write_text(json.dumps({"P1": PLAIN.P1.tolist(), "P2": PLAIN.P2.tolist(), "image_size": [1280, 960]}))
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0, err
    assert "as p34" in stdout
    assert load_calibration(out).image_size == (None if style == "text" else (1280, 960))
    assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-6)


# -- bad input -----------------------------------------------------------------------------------

def test_bad_files_exit_2_naming_file_field_and_fault(tmp_path):
    out = str(tmp_path / "CALIB.json")
    missing = str(tmp_path / "none.yml")
    assert_bad(["--in", missing, "--out", out], "none.yml", "no such file")
    garbage = tmp_path / "garbage.yml"
    garbage.write_text("this: [is: not\n")
    assert_bad(["--in", str(garbage), "--out", out], "garbage.yml", "not an OpenCV FileStorage")
    no_r = tmp_path / "no_r.yml"
    write_opencv(no_r, {k: v for k, v in M_NAMES.items() if k != "R"})
    assert_bad(["--in", str(no_r), "--out", out], "no_r.yml", "R: missing")
    short = tmp_path / "short.txt"
    _write_table(short, _dlt_columns()[:10], "tabs")
    assert_bad(["--in", str(short), "--out", out], "short.txt", "20 numbers")
    assert_bad(["--in", str(short), "--out", out, "--format", "stereomorph"], "short.txt", "coefficients",
               "10 rows x 2 columns")
    word = tmp_path / "word.txt"
    word.write_text("1 2\n3 x4\n")
    assert_bad(["--in", str(word), "--out", out], "word.txt", "line 2", "'x4'")
    nan = tmp_path / "nan.txt"
    _write_table(nan, np.where(np.arange(22).reshape(11, 2) == 5, np.nan, _dlt_columns()), "tabs")
    assert_bad(["--in", str(nan), "--out", out], "nan.txt", "line 3", "not a finite number")
    no_p2 = tmp_path / "p.json"
    no_p2.write_text(json.dumps({"P1": PLAIN.P1.tolist()}))
    assert_bad(["--in", str(no_p2), "--out", out], "p.json", "P2", "missing")
    same = tmp_path / "same.json"
    same.write_text(json.dumps({"P1": PLAIN.P1.tolist(), "P2": PLAIN.P1.tolist()}))
    assert_bad(["--in", str(same), "--out", out], "same.json", "P2", "no baseline")
    good = tmp_path / "cal.txt"
    _write_table(good, _dlt_columns(), "tabs")
    assert_bad(["--in", str(good), "--out", out, "--y-up"], "cal.txt", "--y-up", "--image-size")
    assert_bad(["--in", str(good), "--in", str(good), "--out", out], "cal.txt", "--in", "only OpenCV")
    yml = tmp_path / "ok.yml"
    write_opencv(yml, M_NAMES)
    assert_bad(["--in", str(yml), "--out", out, "--pixel-origin", "one"], "ok.yml", "pixel convention")
    assert_bad(["--in", str(good), "--out", out, "--image-size", "12x"], "--image-size", "WIDTHxHEIGHT")
    assert not Path(out).exists()                                    # nothing written on bad input


def test_a_reflected_rotation_is_refused(tmp_path):
    src = tmp_path / "flip.yml"
    fs = cv2.FileStorage(str(src), cv2.FILE_STORAGE_WRITE)
    for name, value in (("M1", RIG.K1), ("M2", RIG.K2), ("R", R @ np.diag([1.0, 1.0, -1.0])), ("T", T)):
        fs.write(name, value)
    fs.release()
    assert_bad(["--in", str(src), "--out", str(tmp_path / "c.json")], "flip.yml", "R", "not a rotation")


def test_the_installed_command_exits_2_with_one_line(tmp_path):
    run_ = subprocess.run([sys.executable, "-c", "from controller.cli import entry; entry()", "calibrate",
                           "import", "--in", str(tmp_path / "absent.txt"), "--out", str(tmp_path / "c.json")],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert run_.returncode == 2
    assert run_.stderr.strip() == f"fishfarm: {tmp_path / 'absent.txt'}: no such file"
