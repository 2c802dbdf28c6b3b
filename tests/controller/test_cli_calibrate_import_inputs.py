"""``fishfarm calibrate import``: how the input is read — by content whatever its name, once (a
pipe cannot be read twice), gzip'd by its magic bytes, whichever format is named."""
from __future__ import annotations

import gzip
import json
import os

import pytest

from tests.controller.test_cli_calibrate_import import (
    CAMERA1,
    M_NAMES,
    PLAIN,
    RIG,
    WORLD,
    _dlt_columns,
    _write_table,
    assert_bad,
    assert_reconstructs,
    run,
    write_opencv,
    write_stereomorph_calibration,
)


def _p34_text() -> str:
    return "\n".join(" ".join(f"{v:.15g}" for v in row) for row in (*PLAIN.P1, *PLAIN.P2)) + "\n"


@pytest.mark.parametrize("suffix", ["yml", "yaml", "xml"])
def test_a_format_named_on_the_command_line_is_read_whatever_the_files_suffix(tmp_path, suffix):
    """--format p34/stereomorph on a .yml/.yaml/.xml file read no text: an internal error."""
    p34 = tmp_path / f"P.{suffix}"
    p34.write_text(_p34_text())
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(p34), "--out", str(out), "--format", "p34")
    assert code == 0 and "as p34" in stdout, err
    assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-6)
    dlt = tmp_path / f"cal.{suffix}"
    _write_table(dlt, _dlt_columns(), "tabs")
    code, stdout, err = run("--in", str(dlt), "--out", str(out), "--format", "stereomorph")
    assert code == 0 and "as stereomorph" in stdout, err
    assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-4)


@pytest.mark.parametrize("suffix", ["xml", "yml"])
def test_auto_goes_by_content_not_by_the_name(tmp_path, suffix):
    """A StereoMorph calibration.txt saved as .xml was refused as 'not an OpenCV FileStorage file'."""
    src = tmp_path / f"calibration.{suffix}"
    write_stereomorph_calibration(src, _dlt_columns(units_per_mm=0.1))
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0 and "as stereomorph" in stdout, err
    assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-4)
    table = tmp_path / f"cal_coeffs.{suffix}"
    _write_table(table, _dlt_columns(), "tabs")
    code, stdout, err = run("--in", str(table), "--out", str(out))
    assert code == 0 and "as stereomorph" in stdout, err


def test_an_opencv_yaml_file_without_its_header_is_still_opencvs(tmp_path):
    """FileStorage reads YAML without '%YAML': a .txt of 'K1: [...]' lines is OpenCV's by content."""
    yml = tmp_path / "stereo.yml"
    write_opencv(yml, M_NAMES)
    src = tmp_path / "stereo.txt"
    src.write_text(yml.read_text().split("---\n", 1)[1])
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0 and "as opencv" in stdout, err
    assert_reconstructs(out, CAMERA1)


def _pipe(data: bytes) -> str:
    """A pipe holding DATA with its writer closed, as a path (what '<(zcat f)' and /dev/stdin give)."""
    r, w = os.pipe()
    os.write(w, data)             # small: fits the pipe's buffer
    os.close(w)
    return f"/dev/fd/{r}"


@pytest.mark.parametrize("kind", ["opencv", "p34", "opencv-named"])
def test_a_pipe_is_read_once(tmp_path, kind):
    """Sniffing gzip's magic with a buffered read swallowed the pipe: '0 numbers'."""
    yml = tmp_path / "stereo.yml"
    write_opencv(yml, M_NAMES)
    data = _p34_text().encode() if kind == "p34" else yml.read_bytes()
    path = _pipe(data)
    out = tmp_path / "CALIB.json"
    fmt = ["--format", "opencv"] if kind == "opencv-named" else []
    try:
        code, stdout, err = run("--in", path, "--out", str(out), *fmt)
    finally:
        os.close(int(path.rsplit("/", 1)[1]))
    assert code == 0 and f"as {kind.split('-')[0]}" in stdout, err
    if kind == "p34":
        assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-6)
    else:
        assert_reconstructs(out, CAMERA1, rig=RIG)


@pytest.mark.parametrize("name", ["gz_noext.dat", "calib.YML.GZ", "calib.gz", "stereo.yml.gz"])
def test_gzip_is_known_by_its_magic_bytes_whatever_the_name(tmp_path, name):
    yml = tmp_path / "stereo.yml"
    write_opencv(yml, M_NAMES)
    src = tmp_path / name
    src.write_bytes(gzip.compress(yml.read_bytes()))
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0 and "as opencv" in stdout, err
    assert_reconstructs(out, CAMERA1)
    piped = _pipe(src.read_bytes())
    try:
        code, _, err = run("--in", piped, "--out", str(out))
    finally:
        os.close(int(piped.rsplit("/", 1)[1]))
    assert code == 0, err


def test_a_broken_gzip_file_is_one_line(tmp_path):
    src = tmp_path / "calib.yml.gz"
    src.write_bytes(gzip.compress(b"K1: [1, 2]\n" * 50)[:30])
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "calib.yml.gz", "gzip")


def test_a_json_array_as_the_whole_file_is_one_clear_line(tmp_path):
    src = tmp_path / "calib.json"
    src.write_text(json.dumps([PLAIN.P1.tolist(), PLAIN.P2.tolist()]))
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "calib.json", "a JSON array",
               "expected a JSON object")


def test_an_empty_file_says_so(tmp_path):
    src = tmp_path / "calib.yml"
    src.write_text("\n  \n")
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "calib.yml", "empty")
