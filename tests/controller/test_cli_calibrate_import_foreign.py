"""``fishfarm calibrate import`` on files other labs' tools and hands write: keys given twice, two
image sizes, true/false for numbers, numbers no float holds, rotations printed to 4 decimals, ROS's
``rows``/``cols``/``data`` matrices, a lens model that folds inside its image, and the faults of a
camera matrix named for what they are."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from controller.cli.calib_io import load_calibration
from tests.controller.test_cli_calibrate_import import (
    CAMERA1,
    PLAIN,
    RIG,
    R,
    T,
    assert_bad,
    assert_reconstructs,
    run,
)


def _yaml(path: Path, entries: list[tuple[str, np.ndarray | int]]) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in entries:
        fs.write(name, value)
    fs.release()
    return path


CAMERAS = [("M1", RIG.K1), ("D1", RIG.D1.reshape(1, 5)), ("M2", RIG.K2), ("D2", RIG.D2.reshape(1, 5)),
           ("R", R), ("T", T.reshape(3, 1))]


def test_a_matrix_given_twice_is_refused_not_the_first_or_last_taken(tmp_path):
    out = str(tmp_path / "CALIB.json")
    twice = _yaml(tmp_path / "twice.yml", [*CAMERAS, ("M1", RIG.K1 * [[0.75], [0.75], [1]])])
    assert_bad(["--in", str(twice), "--out", out], "twice.yml", "M1", "given twice")
    by_hand = tmp_path / "hand.json"           # json.loads keeps the last of a key given twice
    p1, p2, again = (json.dumps(P.tolist()) for P in (PLAIN.P1, PLAIN.P2, PLAIN.P1))
    by_hand.write_text(f'{{"P1": {p1}, "P2": {p2}, "P2": {again}}}')
    assert_bad(["--in", str(by_hand), "--out", out], "hand.json", "P2", "given twice")
    opencv_names = tmp_path / "names.json"
    k1, k2 = json.dumps(RIG.K1.tolist()), json.dumps(RIG.K2.tolist())
    opencv_names.write_text(f'{{"cameraMatrix1": {k1}, "cameraMatrix1": {k2}}}')
    assert_bad(["--in", str(opencv_names), "--out", out], "names.json", "cameraMatrix1", "given twice")
    assert not Path(out).exists()
    code, _, err = run("--in", str(_yaml(tmp_path / "once.yml", CAMERAS)), "--out", out)
    assert code == 0, err


def test_two_image_sizes_that_disagree_are_refused(tmp_path):
    out = str(tmp_path / "CALIB.json")
    src = tmp_path / "sizes.json"
    doc = {"cameraMatrix1": RIG.K1.tolist(), "cameraMatrix2": RIG.K2.tolist(), "R": R.tolist(), "T": T.tolist(),
           "imageSize": [1280, 960], "image_width": 1920, "image_height": 1080}
    src.write_text(json.dumps(doc))
    assert_bad(["--in", str(src), "--out", out], "1280x960", "1920x1080")
    src.write_text(json.dumps({**doc, "image_width": 1280, "image_height": 960}))
    code, _, err = run("--in", str(src), "--out", out)
    assert code == 0, err
    assert load_calibration(out).image_size == (1280, 960)


@pytest.mark.parametrize("where", ["T", "cameraMatrix1"])
def test_true_or_false_for_a_number_is_refused_by_name(tmp_path, where):
    doc = {"cameraMatrix1": RIG.K1.tolist(), "cameraMatrix2": RIG.K2.tolist(), "R": R.tolist(), "T": T.tolist()}
    doc[where] = [[True, 0, 0]] + doc[where][1:] if where != "T" else [True, 0.0, 0.0]
    src = tmp_path / "flags.json"
    src.write_text(json.dumps(doc))
    assert_bad(["--in", str(src), "--out", str(tmp_path / "c.json")], "flags.json", where, "true/false")
    calib = tmp_path / "CALIB.json"                      # CALIB.json itself, as every command reads it
    calib.write_text(json.dumps({"P1": PLAIN.P1.tolist(), "P2": [[True, *PLAIN.P2[0, 1:].tolist()],
                                                                 *PLAIN.P2[1:].tolist()]}))
    with pytest.raises(Exception, match="P2: not a numeric matrix"):
        load_calibration(calib)


@pytest.mark.parametrize("text,fault", [
    ('{"P1": [[1' + "0" * 400 + ', 0, 640, 0], [0, 1200, 480, 0], [0, 0, 1, 0]], "P2": [[1200, 0, 640, -1e5],'
     ' [0, 1200, 480, 0], [0, 0, 1, 0]]}', "P1: not a numeric matrix"),
    ('{"P1": ' + "[" * 100_000 + "]" * 100_000 + "}", "nested too deep"),
    ('{"P1": [[1' + "0" * 5000 + "]]}", "digits"),
])
def test_numbers_no_float_holds_and_nesting_no_parser_follows_are_one_line(tmp_path, text, fault):
    """Every reader of a calibration: import, and CALIB.json as survey, triangulate and run read it."""
    src = tmp_path / "odd.json"
    src.write_text(text)
    assert_bad(["--in", str(src), "--out", str(tmp_path / "c.json")], "odd.json", fault)
    with pytest.raises(Exception) as got:
        load_calibration(src)
    assert type(got.value).__name__ == "BadInput" and fault in str(got.value) and "use sys." not in str(got.value)
    from devices.stereo.capture import load_calibration as device_loads
    with pytest.raises(ValueError, match="odd.json"):
        device_loads(str(src))


@pytest.mark.parametrize("decimals", [3, 4, 6])
def test_a_rotation_printed_to_a_few_decimals_is_taken_as_the_rotation_nearest_it(tmp_path, decimals):
    rng = np.random.default_rng(decimals)
    worst = 0.0
    for k in range(20):
        Rk = cv2.Rodrigues(rng.normal(0, 0.4, 3))[0]
        src = _yaml(tmp_path / f"r{k}.yml", [("M1", RIG.K1), ("M2", RIG.K2), ("R", np.round(Rk, decimals)),
                                            ("T", T.reshape(3, 1))])
        code, _, err = run("--in", str(src), "--out", str(tmp_path / f"c{k}.json"))
        assert code == 0, err
        got = load_calibration(tmp_path / f"c{k}.json").R
        np.testing.assert_allclose(got @ got.T, np.eye(3), atol=1e-12)
        worst = max(worst, np.degrees(np.arccos(np.clip((np.trace(got.T @ Rk) - 1) / 2, -1, 1))))
    assert worst < 0.1


@pytest.mark.parametrize("K,fault", [(np.diag([-1200.0, 1200.0, 1.0]), "positive"),
                                     (np.array([[1200.0, 0, 640], [50, 1200, 480], [0, 0, 1]]), "upper triangular")])
def test_a_camera_matrix_s_own_fault_is_named(tmp_path, K, fault):
    K = K.copy()
    K[:2, 2] = [640, 480]
    src = _yaml(tmp_path / "k.yml", [("M1", K), ("M2", RIG.K2), ("R", R), ("T", T.reshape(3, 1))])
    assert_bad(["--in", str(src), "--out", str(tmp_path / "c.json")], "k.yml", "K1", fault)


def test_ros_camera_info_matrices_are_read(tmp_path):
    def ros(m):
        m = np.atleast_2d(m)
        return f"\n  rows: {m.shape[0]}\n  cols: {m.shape[1]}\n  data: [{', '.join(repr(float(v)) for v in m.ravel())}]"
    src = tmp_path / "ros_stereo.yaml"
    src.write_text(f"image_width: 1280\nimage_height: 960\ncamera_matrix_left:{ros(RIG.K1)}\n"
                   f"distortion_model: plumb_bob\ndistortion_coefficients_left:{ros(RIG.D1)}\n"
                   f"camera_matrix_right:{ros(RIG.K2)}\ndistortion_coefficients_right:{ros(RIG.D2)}\n"
                   f"R:{ros(R)}\nT:{ros((T / 1000).reshape(3, 1))}\n")
    out = tmp_path / "CALIB.json"
    code, stdout, err = run("--in", str(src), "--out", str(out), "--units", "m")
    assert code == 0, err
    assert "baseline: 400.0 mm" in stdout
    assert_reconstructs(out, CAMERA1)


def test_a_lens_model_folding_inside_its_image_is_said_and_its_far_pixels_written_nan(tmp_path, capsys):
    from controller.cli import main
    K = np.array([[900.0, 0, 960], [0, 900.0, 540], [0, 0, 1]])
    D = np.array([[-0.32, 0.12, 0.0, 0.0, -0.02]])
    src = _yaml(tmp_path / "action.yml", [("M1", K), ("D1", D), ("M2", K), ("D2", D), ("R", np.eye(3)),
                                         ("T", np.array([[-200.0], [0], [0]])), ("image_width", 1920),
                                         ("image_height", 1080)])
    out = tmp_path / "CALIB.json"
    code, _, err = run("--in", str(src), "--out", str(out))
    assert code == 0, err
    said = err.strip().splitlines()
    assert len(said) == 2 and all("folds back" in line and "1920x1080" in line for line in said), err
    assert said[0].startswith("warning: D1") and said[1].startswith("warning: D2")
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("u1,v1,u2,v2\n40,40,25,40\n1000,500,950,500\n")
    assert main(["triangulate", "--calib", str(out), "--pairs", str(pairs), "--out", str(tmp_path / "o.csv")]) == 0
    rows = (tmp_path / "o.csv").read_text().splitlines()
    assert "nan" in rows[1].lower() and "nan" not in rows[2].lower()
    assert "1 pairs (lines 2 of" in capsys.readouterr().err
    code, _, err = run("--in", str(_yaml(tmp_path / "mild.yml", CAMERAS)), "--out", str(tmp_path / "m.json"))
    assert code == 0 and "folds" not in err


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_a_matrix_s_field_given_twice_is_refused_not_the_first_taken(tmp_path, suffix):
    """FileStorage read the first of a matrix's ``data`` written twice, other values in the second
    (an outside tester), and lists neither: the file's top-level keys alone were checked."""
    out = str(tmp_path / "CALIB.json")
    written = _yaml(tmp_path / f"once{suffix}", CAMERAS).read_text()
    scaled = " ".join(f"{v:.6g}" for v in (RIG.K2 * [[0.75], [0.75], [1]]).ravel())
    if suffix == ".yml":
        head, tail = written.split("M2:", 1)
        at = tail.index("data:")
        doubled = f"{head}M2:{tail[:at]}data: [ {scaled.replace(' ', ', ')} ]\n   {tail[at:]}"
    else:
        head, tail = written.split("<M2", 1)
        at = tail.index("<data>")
        doubled = f"{head}<M2{tail[:at]}<data>{scaled}</data>\n  {tail[at:]}"
    twice = tmp_path / f"twice{suffix}"
    twice.write_text(doubled)
    assert_bad(["--in", str(twice), "--out", out], twice.name, "M2.data", "given twice")
    assert not Path(out).exists()
    code, _, err = run("--in", str(tmp_path / f"once{suffix}"), "--out", out)     # the same keys in every matrix
    assert code == 0, err


def test_the_same_keys_in_the_maps_of_a_list_are_not_given_twice(tmp_path):
    """A list of maps (a tool's notes on each camera) has the same keys in every item: no key is
    given twice there, and the file's matrices are imported."""
    out = str(tmp_path / "CALIB.json")
    listed = tmp_path / "listed.yml"
    listed.write_text(_yaml(tmp_path / "once.yml", CAMERAS).read_text()
                      + "cameras_used:\n  - model: a\n    serial: 1\n  - model: b\n    serial: 2\n")
    code, _, err = run("--in", str(listed), "--out", out)
    assert code == 0, err
