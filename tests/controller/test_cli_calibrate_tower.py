"""``fishfarm calibrate tower`` run as the user runs it: a subprocess."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vision.tower import to_pond

FISHFARM = str(Path(sys.executable).parent / "fishfarm")
HEADER = "u,v,x_m,y_m"
# a tower camera's map pond -> pixel (a perspective view of the 20 m x 10 m pond)
G = np.array([[60.0, -8.0, 300.0], [2.0, -30.0, 700.0], [0.0, -0.04, 1.0]])
POND = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 10.0], [0.0, 10.0], [10.0, 5.0], [5.0, 8.0]])


def pixels(pond):
    h = np.c_[pond, np.ones(len(pond))] @ G.T
    return h[:, :2] / h[:, 2:]


def run(*args):
    return subprocess.run([FISHFARM, *map(str, args)], capture_output=True, text=True, timeout=60)


def write(path, text):
    path.write_text(text)
    return path


def ref_text(pond, px=None):
    px = pixels(pond) if px is None else px
    return "\n".join([HEADER] + [f"{u:.6f},{v:.6f},{x},{y}" for (u, v), (x, y) in zip(px, pond, strict=True)]) + "\n"


def test_writes_h_and_prints_the_error_in_metres(tmp_path):
    ref = write(tmp_path / "REF.csv", ref_text(POND))
    out = tmp_path / "TOWER.json"
    result = run("calibrate", "tower", "--points", ref, "--out", out)
    assert result.returncode == 0, result.stderr
    doc = json.loads(out.read_text())
    assert doc["points"] == 6 and doc["rms_m"] < 1e-4 and doc["max_m"] < 1e-4
    np.testing.assert_allclose(to_pond(np.array(doc["H"]), pixels(POND)), POND, atol=1e-4)
    assert result.stdout.count("point ") >= 6 and "error on the pond RMS 0.000 m, worst 0.000 m" in result.stdout
    assert f"written: {out}" in result.stdout


@pytest.mark.parametrize("text, fault", [
    ("", "empty file"),
    ("u,v,x_m\n1,2,3\n", "header: expected 'u,v,x_m,y_m', found 'u,v,x_m'"),
    ("u,v,x_m,y_m,z_m\n1,2,3,4,5\n", "header: expected 'u,v,x_m,y_m', found 'u,v,x_m,y_m,z_m'"),
    (ref_text(POND[:3]), "3 points: at least 4 are needed"),
    (HEADER + "\n1,2,3,4\n5,6,abc,8\n", "line 3, column x_m: not a number: 'abc'"),
    (HEADER + "\n1,2,3,4\n5,nan,7,8\n", "line 3, column v: nan is not a finite number"),
    (HEADER + "\n1,2,3,4\n5,6,7\n", "line 3: 3 fields, expected 4"),
    (HEADER + "\n1,2,3,4\n1e308,100,3,4\n", "line 3: column u: 1e+308 is out of range"),   # it read
    # "points 2 and 3 are the same in the image", after numpy's overflow warnings
    (ref_text(POND[[0, 1, 2, 3, 0]]), "points 1 and 5 are the same in the image"),
    (ref_text(np.array([[0.0, 0.0], [5.0, 1.0], [10.0, 2.0], [15.0, 3.0], [20.0, 4.0]]),
              px=pixels(POND[:5])), "all 5 points lie on one line on the pond"),
    (ref_text(np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [10.0, 10.0]])),
     "points 1, 2, 3 lie on one line in the image"),
])
def test_bad_input_exits_2_with_one_line(tmp_path, text, fault):
    ref = write(tmp_path / "REF.csv", text)
    out = tmp_path / "TOWER.json"
    result = run("calibrate", "tower", "--points", ref, "--out", out)
    assert result.returncode == 2, result.stdout
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert result.stderr.startswith(f"fishfarm: {ref}: ") and fault in result.stderr, result.stderr
    assert not out.exists()


def test_missing_file_and_unwritable_out_exit_2(tmp_path):
    result = run("calibrate", "tower", "--points", tmp_path / "absent.csv", "--out", tmp_path / "T.json")
    assert result.returncode == 2 and result.stderr.strip() == f"fishfarm: {tmp_path / 'absent.csv'}: no such file"
    ref = write(tmp_path / "REF.csv", ref_text(POND))
    (tmp_path / "file").write_text("not a directory")
    bad_out = tmp_path / "file" / "TOWER.json"
    result = run("calibrate", "tower", "--points", ref, "--out", bad_out)
    assert result.returncode == 2 and result.stderr.strip().startswith(f"fishfarm: {bad_out}: --out: cannot write")
    made = tmp_path / "new" / "dir" / "TOWER.json"            # a directory missing is made
    assert run("calibrate", "tower", "--points", ref, "--out", made).returncode == 0 and made.exists()


@pytest.mark.parametrize("flip", ["x from the other end", "y downwards"])
def test_a_survey_that_sees_the_pond_mirrored_is_refused_unless_the_camera_mirrors(tmp_path, flip):
    """No camera above the pond sees it mirrored: an axis measured the other way fits exactly and the
    robot thrashed on it. A camera set to mirror its picture says so with --mirrored-image."""
    measured = POND.copy()
    if flip == "x from the other end":
        measured[:, 0] = 20.0 - measured[:, 0]
    else:
        measured[:, 1] = -measured[:, 1]
    ref = write(tmp_path / "REF.csv", ref_text(measured, px=pixels(POND)))
    out = tmp_path / "TOWER.json"
    result = run("calibrate", "tower", "--points", ref, "--out", out)
    assert result.returncode == 2 and "mirrored" in result.stderr and result.stderr.count("\n") == 1, result.stderr
    assert not out.exists()
    assert run("calibrate", "tower", "--points", ref, "--out", out, "--mirrored-image").returncode == 0
    assert json.loads(out.read_text())["mirrored_image"] is True
    right = write(tmp_path / "RIGHT.csv", ref_text(POND))
    result = run("calibrate", "tower", "--points", right, "--out", tmp_path / "T2.json", "--mirrored-image")
    assert result.returncode == 2 and "leave it out" in result.stderr


def test_a_point_far_off_the_others_fit_is_refused_by_its_line(tmp_path):
    measured = np.vstack([POND, [[12.0, 3.0], [3.0, 2.0]]])
    px = pixels(measured)
    measured[6] = [12.0, 8.0]                              # y mistyped: 8 for 3
    ref = write(tmp_path / "REF.csv", ref_text(measured, px=px))
    result = run("calibrate", "tower", "--points", ref, "--out", tmp_path / "T.json")
    assert result.returncode == 2 and result.stderr.startswith(f"fishfarm: {ref}: line 8: "), result.stderr
    assert "off the fit" in result.stderr and not (tmp_path / "T.json").exists()
    assert run("calibrate", "tower", "--points", ref, "--out", tmp_path / "T.json", "--max-error", "50").returncode == 0


def test_the_frame_size_is_kept_and_pixels_outside_it_refused(tmp_path):
    ref = write(tmp_path / "REF.csv", ref_text(POND))
    out = tmp_path / "TOWER.json"
    assert run("calibrate", "tower", "--points", ref, "--out", out, "--image-size", "2400x800").returncode == 0
    assert json.loads(out.read_text())["image_size"] == [2400, 800]
    result = run("calibrate", "tower", "--points", ref, "--out", tmp_path / "T2.json", "--image-size", "1280x720")
    assert result.returncode == 2 and "outside a 1280x720 frame" in result.stderr
    result = run("calibrate", "tower", "--points", ref, "--out", tmp_path / "T3.json", "--image-size", "12x")
    assert result.returncode == 2 and "--image-size" in result.stderr


def test_a_frame_size_is_held_to_what_track_reads_back(tmp_path):
    """A size past 100000 px a side (or past int64) was written, and `track` refused the file."""
    from controller.cli.track_cmd import load_tower_file
    ref = write(tmp_path / "REF.csv", ref_text(POND))
    for size in ("100001x720", "99999999999999999999x720", "0x720"):
        out = tmp_path / f"T{size[:8]}.json"
        result = run("calibrate", "tower", "--points", ref, "--out", out, "--image-size", size)
        assert result.returncode == 2 and "--image-size" in result.stderr and "1..100000" in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1 and not out.exists(), result.stderr
    out = tmp_path / "TOWER.json"
    assert run("calibrate", "tower", "--points", ref, "--out", out, "--image-size", "100000x100000").returncode == 0
    assert load_tower_file(str(out))[1] == (100000, 100000)
