"""``fishfarm calibrate import`` of OpenCV FileStorage files (written here with cv2.FileStorage, as
the tools write them): the names each tool gives K and D, fisheye models, names given twice."""
from __future__ import annotations

import subprocess
import sys
import warnings

import cv2
import numpy as np
import pytest

from controller.cli.calib_io import load_calibration
from tests.controller.test_cli_calibrate_import import CAMERA1, REPO, RIG, R, T, assert_bad, assert_reconstructs, run


def write_fs(path, items: dict) -> None:
    """A FileStorage file of these keys in this order (numbers, strings, arrays)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in items.items():
        fs.write(name, value if isinstance(value, (int, float, str)) else np.asarray(value, dtype=float))
    fs.release()


def rig_items(k1="K1", d1="D1", k2="K2", d2="D2", d=(RIG.D1, RIG.D2)) -> dict:
    return {k1: RIG.K1, d1: d[0].reshape(1, -1), k2: RIG.K2, d2: d[1].reshape(1, -1), "R": R,
            "T": T.reshape(3, 1), "image_width": 1280, "image_height": 960}


# (K1, D1, K2, D2) as tools name them: OpenCV's samples (camera_matrix, distortion_coefficients),
# left/right, L/R, and 0-based camera numbers (camera 0 is the left)
NAMINGS = [("camera_matrix_1", "distortion_coefficients_1", "camera_matrix_2", "distortion_coefficients_2"),
           ("camera_matrix_left", "distortion_coefficients_left", "camera_matrix_right",
            "distortion_coefficients_right"),
           ("cameraMatrixL", "distCoeffsL", "cameraMatrixR", "distCoeffsR"),
           ("left_camera_matrix", "left_distortion_coefficients", "right_camera_matrix",
            "right_distortion_coefficients"),
           ("K_left", "D_left", "K_right", "D_right"),
           ("mtx_l", "dist_l", "mtx_r", "dist_r"),
           ("camera_matrix_0", "dist_coeffs_0", "camera_matrix_1", "dist_coeffs_1"),
           ("K0", "D0", "K1", "D1")]


@pytest.mark.parametrize("names", NAMINGS, ids=[n[1] for n in NAMINGS])
@pytest.mark.parametrize("ext", ["yml", "xml"])
def test_each_namings_distortion_is_kept_with_its_camera_matrix(tmp_path, names, ext):
    """camera_matrix_left was K1 while distortion_coefficients_left was not D1: D dropped silently."""
    src = tmp_path / f"stereo.{ext}"
    write_fs(src, rig_items(*names))
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0 and "D1/D2 kept" in stdout, err
    calib = load_calibration(out)
    np.testing.assert_allclose(calib.D1, RIG.D1)
    np.testing.assert_allclose(calib.D2, RIG.D2)
    np.testing.assert_allclose(calib.K1, RIG.K1)
    assert_reconstructs(out, CAMERA1)


def test_a_distortion_key_it_does_not_know_is_refused_by_name(tmp_path):
    src = tmp_path / "stereo.yml"
    write_fs(src, rig_items(d1="distortion_params_cam_a", d2="distortion_params_cam_b"))
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "stereo.yml", "distortion_params_cam_a",
               "distortion")


@pytest.mark.parametrize("key, value", [("distortion_model", "fisheye"), ("distortion_model", "equidistant"),
                                        ("model", "Kannala-Brandt"), ("camera_model", "FISHEYE"),
                                        ("fisheye", 1)])
def test_a_fisheye_calibration_is_refused(tmp_path, key, value):
    """cv2.fisheye's k1..k4 were read as the pinhole's k1 k2 p1 p2: lengths up to 28 % long."""
    d1, d2 = np.array([-0.03, 0.01, -0.004, 0.001]), np.array([-0.028, 0.009, -0.003, 0.001])
    src = tmp_path / "fisheye_stereo.yml"
    write_fs(src, {key: value, **rig_items(d=(d1, d2))})
    out = tmp_path / "o.json"
    assert_bad(["--in", str(src), "--out", str(out)], "fisheye_stereo.yml", key, "fisheye", "not supported")
    assert not out.exists()


def test_four_coefficients_and_no_model_named_are_the_pinholes_k1_k2_p1_p2(tmp_path):
    d = (np.array([-0.1, 0.04, 0.0008, -0.0004]), np.array([-0.1, 0.04, 0.0008, -0.0004]))
    src = tmp_path / "d4.yml"
    write_fs(src, {"distortion_model": "plumb_bob", **rig_items(d=d)})
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out))
    assert code == 0 and "D1/D2 kept" in stdout, err
    np.testing.assert_allclose(load_calibration(out).D1, d[0])
    assert_reconstructs(out, CAMERA1)                 # RIG's k3 is 0: the same lens


def test_two_names_of_one_matrix_are_refused_naming_both(tmp_path):
    src = tmp_path / "dup.yml"
    write_fs(src, {**rig_items(), "M1": RIG.K1 * 2})
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "dup.yml", "K1", "M1")


def test_a_field_in_two_files_with_other_values_is_refused(tmp_path):
    a, b = tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml"
    write_fs(a, rig_items())
    write_fs(b, {"R": R, "T": T * 2})
    assert_bad(["--in", str(a), "--in", str(b), "--out", str(tmp_path / "o.json")], "extrinsics.yml", "T",
               "intrinsics.yml")
    write_fs(b, {"R": R, "T": T.reshape(3, 1)})           # the same values twice: one matrix
    assert run("--in", str(a), "--in", str(b), "--out", str(tmp_path / "o.json"))[0] == 0


@pytest.mark.parametrize("given, missing", [("image_width", "image_height"), ("image_height", "image_width")])
def test_half_an_image_size_is_refused_naming_the_missing_key(tmp_path, given, missing):
    items = rig_items()
    del items[missing]
    src = tmp_path / "half.yml"
    write_fs(src, items)
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "half.yml", missing, "missing", given)


def test_a_single_cameras_file_is_missing_k1_not_its_distortion(tmp_path):
    """ROS's camera_info: camera_matrix, distortion_coefficients of one camera."""
    src = tmp_path / "left.yaml"
    write_fs(src, {"camera_matrix": RIG.K1, "distortion_model": "plumb_bob", "distortion_coefficients": RIG.D1})
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "left.yaml", "K1", "missing")


def test_an_image_size_without_both_principal_points_is_refused_naming_its_key(tmp_path):
    src = tmp_path / "stereo.yml"
    write_fs(src, rig_items())
    out = tmp_path / "o.json"
    cx = RIG.K1[0, 2]
    assert_bad(["--in", str(src), "--out", str(out), "--image-size", f"{int(cx) - 10}x960"], "stereo.yml",
               "--image-size", "K1", "principal point")
    items = rig_items()
    items["image_width"] = int(cx) - 10
    write_fs(src, items)
    assert_bad(["--in", str(src), "--out", str(out)], "stereo.yml", "image_size", "K1", "principal point")
    assert not out.exists()


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "0"])
def test_square_mm_not_a_finite_size_is_blamed_on_square_mm(tmp_path, value):
    src = tmp_path / "stereo.yml"
    write_fs(src, rig_items())
    with warnings.catch_warnings():
        warnings.simplefilter("error")                   # numpy's warnings were extra stderr lines
        assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json"), "--square-mm", value], "--square-mm")


@pytest.mark.parametrize("t", [1e308, 1e300])
def test_a_translation_too_large_is_one_line_naming_t(tmp_path, t):
    src = tmp_path / "bigT.yml"
    write_fs(src, {**rig_items(), "T": np.array([-t, 0.0, 0.0])})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json"), "--units", "m"], "bigT.yml", "T")


def test_the_installed_command_says_a_huge_t_in_one_line(tmp_path):
    src = tmp_path / "bigT.yml"
    write_fs(src, {**rig_items(), "T": np.array([-1e308, 0.0, 0.0])})
    done = subprocess.run([sys.executable, "-c", "from controller.cli import entry; entry()", "calibrate", "import",
                           "--in", str(src), "--out", str(tmp_path / "c.json")],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert done.stderr.startswith(f"fishfarm: {src}: T: "), done.stderr


@pytest.mark.parametrize("text", ["%YAML:1.0\n", "%YAML:1.0\n---\n- 1\n- 2\n", "%YAML 1.2\n---\n"])
def test_a_file_with_no_map_of_matrices_is_one_line_not_an_internal_error(tmp_path, text):
    """FileStorage's keys() asserted on an empty or list root: exit 1, 'internal error' (outside tester)."""
    src = tmp_path / "c.yml"
    src.write_text(text)
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "c.yml", "no map of named matrices")


@pytest.mark.parametrize("ext", ["yml", "xml", "json"])
def test_two_spellings_of_the_image_size_that_disagree_are_refused(tmp_path, ext):
    """image_size and imageSize are one name to the import: the last one read won, without a word."""
    src = tmp_path / f"c.{ext}"
    items = {**rig_items(), "image_size": np.array([[1280.0, 960.0]]), "imageSize": np.array([[1300.0, 1000.0]])}
    del items["image_width"], items["image_height"]
    write_fs(src, items)
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], f"c.{ext}", "image_size", "imageSize",
               "two names")


def test_a_camera_0_beside_cameras_1_and_2_is_refused(tmp_path):
    """K0 made the file 0-based: camera 2 took the file's K1, K2 and D2 were dropped, and camera 1
    imported without the distortion the output said it kept."""
    src = tmp_path / "c.yml"
    write_fs(src, {**rig_items(), "K0": RIG.K1})
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "c.yml", "K0", "three cameras")


def test_a_matrix_whose_type_cannot_hold_its_values_is_refused(tmp_path):
    src = tmp_path / "c.yml"
    write_fs(src, rig_items())
    text = src.read_text()
    head = text.index("K1: !!opencv-matrix")
    src.write_text(text[:head] + text[head:].replace("dt: d", "dt: u", 1))    # 1100 px read as 255
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "c.yml", "K1", "dt 'u'")


def test_nan_in_a_json_file_names_its_key(tmp_path):
    import json
    src = tmp_path / "c.json"
    src.write_text(json.dumps({"K1": RIG.K1.tolist(), "D1": RIG.D1.tolist(), "K2": RIG.K2.tolist(),
                               "D2": RIG.D2.tolist(), "R": R.tolist(), "T": [float("nan"), 0.0, 0.0]}))
    assert_bad(["--in", str(src), "--out", str(tmp_path / "o.json")], "c.json", "T", "NaN", "finite")
