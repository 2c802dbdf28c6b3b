"""``fishfarm calibrate dlt`` and ``fishfarm triangulate`` run as the user runs them: a subprocess."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller.cli.calib_io import load_calibration, save_calibration
from devices.sim.stereo_rig import (
    convergent_rig,
    measure_grid,
    random_points_in_grid_volume,
    two_plane_object,
)

FISHFARM = str(Path(sys.executable).parent / "fishfarm")
GRID_HEADER = "x_mm,y_mm,z_mm,u1,v1,u2,v2"
RIG = convergent_rig()
WORLD = two_plane_object()


def run(*args, cwd=None):
    return subprocess.run([FISHFARM, *map(str, args)], capture_output=True, text=True, timeout=60, cwd=cwd)


def write_csv(path, header, rows):
    lines = [header] + [",".join(f"{v:.6f}" if isinstance(v, float) else str(v) for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def grid_file(tmp_path_factory):
    grid = measure_grid(RIG, WORLD, 0.2, np.random.default_rng(21))
    return write_csv(tmp_path_factory.mktemp("grid") / "GRID.csv", GRID_HEADER, grid.tolist())


@pytest.fixture(scope="module")
def calibrated(grid_file):
    out = grid_file.parent / "CALIB.json"
    report = grid_file.parent / "REPORT.json"
    result = run("calibrate", "dlt", "--points", grid_file, "--out", out, "--report", report)
    return result, out, report


def test_calibrate_writes_p1_p2_and_prints_the_validation_report(calibrated):
    result, out, report_path = calibrated
    assert result.returncode == 0, result.stderr
    calib = load_calibration(out)
    clean1, clean2 = RIG.project(WORLD)
    for P, clean in ((calib.P1, clean1), (calib.P2, clean2)):
        h = np.c_[WORLD, np.ones(len(WORLD))] @ P.T
        assert np.abs(h[:, :2] / h[:, 2:] - clean).max() < 0.5
    report = json.loads(report_path.read_text())
    assert report["points"] == 100 and report["pairs"] == 4950
    assert 0.15 < report["rms_px"][0] < 0.4 and 0.15 < report["rms_px"][1] < 0.4
    d = report["distance_error_pct"]
    assert 0 < d["median"] < d["p95"] < d["max"] < 10
    text = result.stdout
    assert f"camera 1 {report['rms_px'][0]:.3f} px" in text
    assert f"camera 2 {report['rms_px'][1]:.3f} px" in text
    assert f"median {d['median']:.4f} %" in text and f"p95 {d['p95']:.4f} %" in text
    assert f"max {d['max']:.4f} %" in text
    # the out-of-sample check: every point predicted by a calibration that never saw it
    held = report["out_of_sample"]
    assert held["folds"] == 10 and held["points"] == 100 and held["pairs"] == 4950
    assert report["rms_px"][0] < held["rms_px"][0] < 2 * report["rms_px"][0]
    e, hd = held["point_error_mm"], held["distance_error_pct"]
    assert 0 < e["median"] < e["p95"] < e["max"] < 5
    assert ("held-out check (10 folds, 100 points" in text and f"camera 1 {held['rms_px'][0]:.3f} px" in text)
    assert f"point error median {e['median']:.3f} mm" in text and f"p95 {hd['p95']:.4f} %" in text
    assert report["grid"]["thickness_ratio"] > 0.3 and "ratio 0.322" in text and "warning" not in text
    assert load_calibration(out).extra["validation"]["out_of_sample"]["points"] == 100


def test_triangulate_reconstructs_pairs_in_order(calibrated, tmp_path):
    _, calib_path, _ = calibrated
    truth = random_points_in_grid_volume(WORLD, 50, np.random.default_rng(5))
    p1, p2 = RIG.project(truth)
    pairs = write_csv(tmp_path / "PAIRS.csv", "u1,v1,u2,v2", np.c_[p1, p2].tolist())
    out = tmp_path / "OUT.csv"
    result = run("triangulate", "--calib", calib_path, "--pairs", pairs, "--out", out)
    assert result.returncode == 0, result.stderr
    lines = out.read_text().splitlines()
    assert lines[0] == "x_mm,y_mm,z_mm,residual_px"
    got = np.loadtxt(out, delimiter=",", skiprows=1)
    assert got.shape == (50, 4)
    # calibrated from a noisy grid: the frame may be off by a fraction of a mm, not the order of rows
    assert np.abs(got[:, :3] - truth).max() < 1.5
    assert np.all(got[:, 3] >= 0) and got[:, 3].max() < 0.5
    to_stdout = run("triangulate", "--calib", calib_path, "--pairs", pairs)
    assert to_stdout.returncode == 0 and to_stdout.stdout == out.read_text()


def test_triangulate_undistorts_with_a_full_calibration(tmp_path):
    rig = convergent_rig(distortion=np.array([-0.15, 0.08, 0.0, 0.0, 0.0]))
    calib_path = tmp_path / "CALIB.json"
    save_calibration(rig.calibration(), calib_path)
    truth = random_points_in_grid_volume(WORLD, 20, np.random.default_rng(6))
    pairs = write_csv(tmp_path / "PAIRS.csv", "u1,v1,u2,v2", np.hstack(rig.project(truth)).tolist())
    result = run("triangulate", "--calib", calib_path, "--pairs", pairs)
    assert result.returncode == 0, result.stderr
    got = np.loadtxt(result.stdout.splitlines()[1:], delimiter=",")
    assert np.abs(got[:, :3] - truth).max() < 0.01


def test_triangulate_header_only_gives_header_only(calibrated, tmp_path):
    pairs = tmp_path / "PAIRS.csv"
    pairs.write_text("u1,v1,u2,v2\n")
    result = run("triangulate", "--calib", calibrated[1], "--pairs", pairs)
    assert result.returncode == 0 and result.stdout == "x_mm,y_mm,z_mm,residual_px\n"


def _grid_rows(world):
    p1, p2 = RIG.project(world)
    return np.c_[world, p1, p2].tolist()


def _dlt_case(name):
    """(file text, words the one-line error must contain) for each bad GRID.csv."""
    rows = _grid_rows(WORLD)
    good = [GRID_HEADER] + [",".join(f"{v:.4f}" for v in r) for r in rows]
    if name == "empty":
        return "", ["empty"]
    if name == "header":
        return "\n".join(["x,y,z,u1,v1,u2,v2"] + good[1:]), ["header", GRID_HEADER]
    if name == "text_cell":
        bad = good.copy()
        cells = bad[5].split(",")
        cells[4] = "abc"
        bad[5] = ",".join(cells)
        return "\n".join(bad), ["line 6", "column v1", "abc"]  # list index 5 = file line 6
    if name == "nan_cell":
        bad = good.copy()
        bad[7] = ",".join(["nan"] + bad[7].split(",")[1:])
        return "\n".join(bad), ["line 8", "column x_mm", "finite"]
    if name == "short_row":
        bad = good.copy()
        bad[3] = ",".join(bad[3].split(",")[:6])
        return "\n".join(bad), ["line 4", "6 fields"]
    if name == "five_points":
        return "\n".join(good[:6]), ["5 points", "at least 6"]
    if name == "coplanar":
        return "\n".join(good[:51]), ["coplanar"]
    if name == "thin":           # two layers of one plate 5 mm apart: 3-D only on paper
        layers = np.vstack([WORLD[:50], WORLD[:50] + [0.0, 5.0, 0.0]])
        text = [GRID_HEADER] + [",".join(f"{v:.4f}" for v in r) for r in _grid_rows(layers)]
        return "\n".join(text), ["coplanar", "thickness 2.5 mm", "extent of 143.6 mm", "at least 0.05"]
    if name == "huge_pixel":
        bad = good.copy()
        cells = bad[4].split(",")
        cells[5] = "1e308"
        bad[4] = ",".join(cells)
        return "\n".join(bad), ["line 5", "column u2", "out of range"]
    if name == "repeated":       # a point listed twice: its report's distance 0 made NaN, Infinity in JSON
        bad = good + [good[3], good[9]]
        return "\n".join(bad), ["points 3 and", "are the same world point"]
    if name == "collinear":
        line = np.outer(np.linspace(0, 1, 10), [300.0, 200.0, 100.0])
        text = [GRID_HEADER] + [",".join(f"{v:.4f}" for v in r) for r in _grid_rows(line)]
        return "\n".join(text), ["line"]
    raise KeyError(name)


def assert_one_line(result, *words):
    assert result.returncode == 2, (result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    for word in words:
        assert str(word) in lines[0], (word, lines[0])


@pytest.mark.parametrize("case", ["empty", "header", "text_cell", "nan_cell", "short_row", "five_points",
                                  "coplanar", "thin", "collinear", "repeated", "huge_pixel"])
def test_bad_grid_exits_2_with_one_line_naming_file_and_fault(case, tmp_path):
    text, words = _dlt_case(case)
    grid = tmp_path / "GRID.csv"
    grid.write_text(text)
    result = run("calibrate", "dlt", "--points", grid, "--out", tmp_path / "CALIB.json")
    assert_one_line(result, grid, *words)
    assert not (tmp_path / "CALIB.json").exists()


def test_missing_grid_file(tmp_path):
    missing = tmp_path / "nowhere.csv"
    assert_one_line(run("calibrate", "dlt", "--points", missing, "--out", tmp_path / "c.json"),
                    missing, "no such file")


def test_unwritable_outputs(grid_file, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    out = blocker / "CALIB.json"
    assert_one_line(run("calibrate", "dlt", "--points", grid_file, "--out", out), out, "cannot write")
    report = blocker / "REPORT.json"
    assert_one_line(run("calibrate", "dlt", "--points", grid_file, "--out", tmp_path / "c.json",
                        "--report", report), report, "cannot write")


def _calib_text(case):
    P = RIG.P1.tolist()
    if case == "no_p1":
        return json.dumps({"P2": P}), ["P1", "missing"]
    if case == "singular":
        singular = np.array(P)
        singular[2, :3] = 0.0
        return json.dumps({"P1": P, "P2": singular.tolist()}), ["P2", "singular"]
    if case == "not_json":
        return "{P1: oops", ["not valid JSON"]
    if case == "null_p1":
        return json.dumps({"P1": None, "P2": RIG.P2.tolist()}), ["P1", "missing (null)"]
    full = RIG.calibration().to_json() | {"D1": [-0.1, 0.05, 0.0, 0.0, 0.0]}
    if case == "zero_k1":
        return json.dumps(full | {"K1": np.zeros((3, 3)).tolist()}), ["K1", "singular"]
    if case == "k1_last_row":
        K = RIG.K1.copy()
        K[2] = [0.0, 0.0, 2.0]
        return json.dumps(full | {"K1": K.tolist()}), ["K1", "last row", "expected [0, 0, 1]"]
    if case == "one_centre":
        return json.dumps({"P1": P, "P2": (3 * RIG.P1).tolist()}), ["P2", "same camera centre", "no baseline"]
    raise KeyError(case)


@pytest.mark.parametrize("case", ["no_p1", "singular", "not_json", "null_p1", "zero_k1", "k1_last_row",
                                  "one_centre"])
def test_bad_calibration_file(case, tmp_path):
    text, words = _calib_text(case)
    calib = tmp_path / "CALIB.json"
    calib.write_text(text)
    pairs = write_csv(tmp_path / "PAIRS.csv", "u1,v1,u2,v2", [[1.0, 2.0, 3.0, 4.0]])
    assert_one_line(run("triangulate", "--calib", calib, "--pairs", pairs), calib, *words)


@pytest.mark.parametrize("text, words", [
    ("u1,v1,u2\n1,2,3\n", ["header", "u1,v1,u2,v2"]),
    ("u1,v1,u2,v2\n1,2,3,4\n1,2,NaN,4\n", ["line 3", "column u2", "finite"]),
    ("u1,v1,u2,v2\n1,2,3,x4\n", ["line 2", "column v2", "'x4'"]),
    # finite, but beyond any image: NaN rows and numpy's overflow warnings before
    ("u1,v1,u2,v2\n1,2,3,4\n\n1,2,1e300,4\n", ["line 4", "column u2", "1e+300 is out of range"]),
    ("u1,v1,u2,v2\n-2e6,2,3,4\n", ["line 2", "column u1", "-2e+06 is out of range"]),
    # a row of empty cells is a row: dropped, every later output row stood beside the wrong input one
    ("u1,v1,u2,v2\n650,470,540,470\n,,,\n700,500,590,500\n", ["line 3", "column u1", "not a number: ''"]),
])
def test_bad_pairs_file(calibrated, tmp_path, text, words):
    pairs = tmp_path / "PAIRS.csv"
    pairs.write_text(text)
    assert_one_line(run("triangulate", "--calib", calibrated[1], "--pairs", pairs), pairs, *words)


def test_missing_option_is_one_line(tmp_path):
    assert_one_line(run("triangulate", "--pairs", tmp_path / "p.csv"), "--calib")


@pytest.mark.parametrize("row, column, typo", [(0, "u1", 300.0), (37, "v2", -100.0), (99, "u2", 40.0)])
def test_a_mistyped_pixel_is_refused_naming_its_line(grid_file, tmp_path, row, column, typo):
    """One pixel mistyped (a digit): the fit took it, 3-D distances up to 701 % off, exit 0 (an
    outside tester). Refused naming the line, unless --max-error allows it."""
    lines = grid_file.read_text().splitlines()
    cells = lines[row + 1].split(",")
    k = GRID_HEADER.split(",").index(column)
    cells[k] = f"{float(cells[k]) + typo:.6f}"
    lines[row + 1] = ",".join(cells)
    bad = tmp_path / "typo.csv"
    bad.write_text("\n".join(lines) + "\n")
    result = run("calibrate", "dlt", "--points", bad, "--out", tmp_path / "c.json")
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    cam = column[-1]
    assert f"typo.csv: line {row + 2}: (u{cam}, v{cam}) = " in result.stderr and "mistyped" in result.stderr
    assert not (tmp_path / "c.json").exists()
    result = run("calibrate", "dlt", "--points", bad, "--out", tmp_path / "c.json", "--max-error", 1000)
    assert result.returncode == 0, result.stderr


def test_pixels_read_a_few_pixels_off_are_a_calibration_not_a_typo(tmp_path):
    grid = measure_grid(RIG, WORLD, 4.0, np.random.default_rng(5))    # clicked by hand, 4 px sd
    path = write_csv(tmp_path / "GRID.csv", GRID_HEADER, grid.tolist())
    result = run("calibrate", "dlt", "--points", path, "--out", tmp_path / "c.json")
    assert result.returncode == 0, result.stderr
