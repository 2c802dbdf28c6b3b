"""``fishfarm calibrate import`` of 3x4 pairs: CALIB.json's own form (DESIGN.md: P1, P2 and optional
K1 D1 K2 D2 R T image_size rms_px) round-trips whole; text tables only in the layouts of two 3x4s."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from controller.cli.calib_io import load_calibration
from tests.controller.test_cli_calibrate_import import (
    CAMERA1,
    M_NAMES,
    PLAIN,
    RIG,
    WORLD,
    R,
    T,
    _dlt_columns,
    assert_bad,
    assert_reconstructs,
    run,
    write_opencv,
)


def calib_json(unit_mm: float = 1.0) -> dict:
    """DESIGN.md's CALIB.json of RIG in camera 1's frame, its world in a unit of UNIT_MM mm."""
    to_unit = np.diag([unit_mm] * 3 + [1.0])          # P maps world units: x_mm = unit_mm * x_unit
    P1 = RIG.K1 @ np.c_[np.eye(3), np.zeros(3)] @ to_unit
    P2 = RIG.K2 @ np.c_[R, T] @ to_unit
    return {"P1": P1.tolist(), "P2": P2.tolist(), "K1": RIG.K1.tolist(), "D1": RIG.D1.tolist(),
            "K2": RIG.K2.tolist(), "D2": RIG.D2.tolist(), "R": R.tolist(), "T": (T / unit_mm).tolist(),
            "image_size": [1280, 960], "rms_px": 0.21, "pairs_used": 14}


def test_a_calib_json_imports_keeping_everything_it_has(tmp_path):
    """CALIB.json was read as a bare 3x4 pair: D1/D2, K, R, T dropped ('other fields ignored')."""
    src = tmp_path / "cb.json"
    src.write_text(json.dumps(calib_json()))
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0 and "as p34" in stdout and "D1/D2 kept" in stdout, err
    calib = load_calibration(out)
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        np.testing.assert_allclose(getattr(calib, name), calib_json()[name], err_msg=name)
    assert calib.image_size == (1280, 960) and calib.rms_px == 0.21 and calib.extra["pairs_used"] == 14
    assert_reconstructs(out, CAMERA1)                     # distorted pixels: only right with D kept


def test_fishfarms_own_output_round_trips(tmp_path):
    yml = tmp_path / "stereo.yml"
    write_opencv(yml, M_NAMES)
    first, second = tmp_path / "first.json", tmp_path / "second.json"
    assert run("--in", str(yml), "--out", str(first))[0] == 0
    code, _, err = run("--in", str(first), "--out", str(second))
    assert code == 0, err
    a, b = json.loads(first.read_text()), json.loads(second.read_text())
    assert {k: v for k, v in a.items() if k not in ("format", "source")} == \
           {k: v for k, v in b.items() if k not in ("format", "source")}


def test_a_calib_json_in_cm_is_scaled_whole(tmp_path):
    src = tmp_path / "cm.json"
    src.write_text(json.dumps(calib_json(unit_mm=10.0)))
    out = tmp_path / "CALIB.json"
    code, _, err = run("--in", str(src), "--out", str(out), "--units", "cm")
    assert code == 0, err
    np.testing.assert_allclose(load_calibration(out).T, T, atol=1e-9)
    assert_reconstructs(out, CAMERA1)


@pytest.mark.parametrize("drop, field", [("K1", "D1"), ("K2", "D2")])
def test_distortion_without_its_camera_matrix_is_refused_not_dropped(tmp_path, drop, field):
    src = tmp_path / "half.json"
    doc = {k: v for k, v in calib_json().items() if k != drop}
    src.write_text(json.dumps(doc))
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "half.json", field, f"without {drop}")


def test_another_tools_name_beside_p1_p2_is_refused_not_ignored(tmp_path):
    src = tmp_path / "p.json"
    src.write_text(json.dumps({"P1": PLAIN.P1.tolist(), "P2": PLAIN.P2.tolist(), "distCoeffs1": RIG.D1.tolist()}))
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "p.json", "distCoeffs1", "D1")


def test_a_pixel_convention_is_refused_where_k_and_d_are_opencvs(tmp_path):
    src = tmp_path / "cb.json"
    src.write_text(json.dumps(calib_json()))
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json"), "--pixel-origin", "one"], "cb.json",
               "--pixel-origin", "K1")


def _rows(mats, by) -> str:
    return "\n".join(" ".join(repr(float(v)) for v in row) for row in by(mats)) + "\n"


@pytest.mark.parametrize("layout", ["6x4", "2x12", "1x24"])
def test_the_layouts_of_two_3x4_matrices(tmp_path, layout):
    by = {"6x4": lambda m: np.vstack(m), "2x12": lambda m: [p.reshape(-1) for p in m],
          "1x24": lambda m: [np.concatenate([p.reshape(-1) for p in m])]}[layout]
    src = tmp_path / "P.txt"
    src.write_text(_rows((PLAIN.P1, PLAIN.P2), by))
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0 and "as p34" in stdout, err
    assert_reconstructs(out, WORLD, rig=PLAIN, atol=1e-6)


@pytest.mark.parametrize("layout, shape", [("3x8", "3 rows x 8 columns"), ("8x3", "8 rows x 3 columns"),
                                           ("12x2", "12 rows x 2 columns"), ("4x6", "4 rows x 6 columns")])
def test_24_numbers_in_another_layout_are_refused_naming_it(tmp_path, layout, shape):
    """Any 24 numbers were P1 then P2 row by row: a 12x2 DLT table and side-by-side 3x8 gave nonsense."""
    if layout == "12x2":                     # DLT-12: StereoMorph's 11 coefficients per camera and L12 = 1
        table = np.vstack([_dlt_columns(), [1.0, 1.0]])
    else:
        table = {"3x8": np.hstack([PLAIN.P1, PLAIN.P2]), "8x3": np.vstack([PLAIN.P1.T, PLAIN.P2.T]),
                 "4x6": np.vstack([PLAIN.P1, PLAIN.P2]).reshape(4, 6)}[layout]
    src = tmp_path / "P.txt"
    src.write_text(_rows(table, lambda t: t))
    for fmt in ("auto", "p34"):
        assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json"), "--format", fmt], "P.txt", shape,
                   "6 rows of 4")


@pytest.mark.parametrize("style", ["text", "json"])
def test_a_camera_centre_out_of_any_rigs_reach_is_one_line(tmp_path, style):
    """Its baseline's norm overflowed: numpy's warning on stderr, then 'same camera centre as P1'."""
    P2 = PLAIN.P2.copy()
    P2[:, 3] *= 1e300 / np.abs(P2[:, 3]).max()
    src = tmp_path / f"big.{'txt' if style == 'text' else 'json'}"
    if style == "text":
        src.write_text(_rows((PLAIN.P1, P2), np.vstack))
    else:
        src.write_text(json.dumps({"P1": PLAIN.P1.tolist(), "P2": P2.tolist()}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], src.name, "P2", "camera centre")


def test_y_up_with_a_size_too_small_blames_the_size(tmp_path):
    src = tmp_path / "P.txt"
    src.write_text(_rows((PLAIN.P1, PLAIN.P2), np.vstack))
    out = str(tmp_path / "o.json")
    assert_bad(["--in", str(src), "--out", out, "--y-up"], "P.txt", "--y-up", "--image-size")
    assert_bad(["--in", str(src), "--out", out, "--y-up", "--image-size", "100x100"], "P.txt", "--image-size",
               "principal point")
