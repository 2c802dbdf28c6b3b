"""``fishfarm calibrate chessboard`` as a user runs it: a subprocess, exit codes, one-line errors."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from controller.cli.calib_io import load_calibration
from devices.sim.stereo_scene import board_session, random_texture
from tests.controller.huge_images import huge_jpeg, huge_png
from tests.vision.shared_data import SHARED_DATA, needs_data, require

REPO = Path(__file__).resolve().parents[2]
DATA = SHARED_DATA / "stereo-chessboard"
IMAGES = "real chessboard images"


def fishfarm(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-c", "from controller.cli import entry; entry()", "calibrate", "chessboard"]
    return subprocess.run([*cmd, *args],
                          cwd=REPO, capture_output=True, text=True, timeout=120)


def assert_bad_input(run: subprocess.CompletedProcess, *words: str) -> None:
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in run.stderr, run.stderr
    for word in words:
        assert word in lines[0], lines[0]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("boards")
    for i, (a, b) in enumerate(board_session(8, np.random.default_rng(3)).pairs):
        cv2.imwrite(str(folder / f"L{i:02d}.png"), a)
        cv2.imwrite(str(folder / f"R{i:02d}.png"), b)
    return folder


def args(folder: Path, out: Path, left="L*.png", right="R*.png", pattern="9x6", square="25"):
    return ("--left", str(folder / left), "--right", str(folder / right), "--pattern", pattern,
            "--square-mm", square, "--out", str(out))


def test_rendered_boards_write_a_calibration_of_the_true_rig(rendered, tmp_path):
    out = tmp_path / "calib" / "CALIB.json"
    run = fishfarm(*args(rendered, out))
    assert run.returncode == 0, run.stderr
    assert "pairs: 8 given, 8 used, 0 rejected" in run.stdout
    assert "RMS reprojection error" in run.stdout and "mean epipolar error" in run.stdout
    assert "baseline: 3.200 squares (80.0 mm)" in run.stdout            # camera 2 is 80 mm away
    calib = load_calibration(out)
    assert np.linalg.norm(calib.T) == pytest.approx(80.0, rel=0.005)
    assert calib.image_size == (640, 480) and calib.rms_px < 0.1
    assert calib.extra["pairs_used"] == 8 and calib.extra["square_mm"] == 25.0


@needs_data(DATA, IMAGES)            # skip when absent, unless CI / FISHFARM_REQUIRE_DATA: then fail
def test_real_images(tmp_path):
    require(DATA, IMAGES)
    out = tmp_path / "CALIB.json"
    run = fishfarm("--left", str(DATA / "left*.jpg"), "--right", str(DATA / "right*.jpg"), "--pattern", "9x6",
                   "--square-mm", "25", "--out", str(out))
    assert run.returncode == 0, run.stderr
    assert "pairs: 13 given, 13 used, 0 rejected" in run.stdout
    calib = load_calibration(out)
    assert np.linalg.norm(calib.T) / 25 == pytest.approx(3.33, abs=0.03)   # OpenCV's sample: 3.34


def test_the_same_views_given_as_left_and_right_are_refused_not_written(rendered, tmp_path):
    """A calibration of one camera against itself has no baseline: every command refuses such a
    CALIB.json, so the calibration that would write it says so instead (it exited 0)."""
    out = tmp_path / "c.json"
    assert_bad_input(fishfarm(*args(rendered, out, right="L*.png")), "P2", "no baseline",
                     "the same camera's views")
    assert not out.exists()


def test_no_file_matches_the_glob(rendered, tmp_path):
    assert_bad_input(fishfarm(*args(rendered, tmp_path / "c.json", left="X*.png")), "X*.png", "--left",
                     "no files match")


def test_count_mismatch(rendered, tmp_path):
    assert_bad_input(fishfarm(*args(rendered, tmp_path / "c.json", right="R0[0-6].png")),
                     "R0[0-6].png", "7 files, but --left matches 8")


def test_unreadable_image(rendered, tmp_path):
    for i in range(3):
        (tmp_path / f"L{i}.png").write_bytes((rendered / f"L0{i}.png").read_bytes())
        (tmp_path / f"R{i}.png").write_bytes((rendered / f"R0{i}.png").read_bytes())
    (tmp_path / "R1.png").write_bytes(b"not a picture at all")
    assert_bad_input(fishfarm(*args(tmp_path, tmp_path / "c.json")), "R1.png", "not a readable image")


def test_an_image_declaring_more_pixels_than_opencv_reads(rendered, tmp_path):
    for name, data in (("L1.png", huge_png()), ("L1.jpg", huge_jpeg())):
        folder = tmp_path / name
        folder.mkdir()
        (folder / name).write_bytes(data)
        (folder / "R1.png").write_bytes((rendered / "R01.png").read_bytes())
        assert_bad_input(fishfarm(*args(folder, tmp_path / "c.json", left="L1.*", right="R1.png")),
                         name, "too large: over 2^30 pixels")


def test_image_size_mismatch(rendered, tmp_path):
    for i in range(3):
        for side in "LR":
            img = cv2.imread(str(rendered / f"{side}0{i}.png"), cv2.IMREAD_GRAYSCALE)
            if (side, i) == ("R", 2):
                img = cv2.resize(img, (320, 240))
            cv2.imwrite(str(tmp_path / f"{side}{i}.png"), img)
    assert_bad_input(fishfarm(*args(tmp_path, tmp_path / "c.json")), "R2.png", "320x240", "640x480")


def test_board_not_found_in_any_pair(tmp_path):
    rng = np.random.default_rng(0)
    for i in range(2):               # pictures of something else (detection gives up in ~0.5 s each)
        for side in "LR":
            picture = (255 * random_texture((480, 640), rng)).astype(np.uint8)
            cv2.imwrite(str(tmp_path / f"{side}{i}.png"), picture)
    assert_bad_input(fishfarm(*args(tmp_path, tmp_path / "c.json")), "L*.png", "--pattern 9x6",
                     "board not found in any of the 2 pairs")
    assert not (tmp_path / "c.json").exists()


def test_board_found_in_too_few_pairs(rendered, tmp_path):
    rng = np.random.default_rng(1)
    for i in range(3):
        for side in "LR":
            img = cv2.imread(str(rendered / f"{side}0{i}.png"), cv2.IMREAD_GRAYSCALE)
            if (side, i) == ("R", 1):
                img = rng.integers(0, 255, img.shape, dtype=np.uint8)     # the board left the view
            cv2.imwrite(str(tmp_path / f"{side}{i}.png"), img)
    run = fishfarm(*args(tmp_path, tmp_path / "c.json"))
    assert_bad_input(run, "L*.png", "only 2 of 3 pairs", "board not found in right: 1 pair(s), e.g. L1.png")


@pytest.mark.parametrize("pattern", ["9by6", "2x6", "9x", ""])
def test_bad_pattern(rendered, tmp_path, pattern):
    assert_bad_input(fishfarm(*args(rendered, tmp_path / "c.json", pattern=pattern)), "--pattern")


@pytest.mark.parametrize("square", ["0", "-3", "big"])
def test_bad_square_size(rendered, tmp_path, square):
    assert_bad_input(fishfarm(*args(rendered, tmp_path / "c.json", square=square)), "--square-mm")


def test_out_cannot_be_written(rendered, tmp_path):
    (tmp_path / "taken").mkdir()
    assert_bad_input(fishfarm(*args(rendered, tmp_path / "taken")), "--out", "directory")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert_bad_input(fishfarm(*args(rendered, blocker / "CALIB.json")), str(blocker / "CALIB.json"),
                     "cannot write")


def test_mixed_up_pairs_are_reported_and_the_rest_calibrate_the_true_rig(rendered, tmp_path):
    folder = tmp_path / "mixed"
    folder.mkdir()
    for f in rendered.glob("*.png"):
        (folder / f.name).write_bytes(f.read_bytes())
    (folder / "R02.png").write_bytes((rendered / "R05.png").read_bytes())
    (folder / "R05.png").write_bytes((rendered / "R02.png").read_bytes())
    run = fishfarm(*args(folder, tmp_path / "c.json"))
    assert run.returncode == 0, run.stderr
    assert "8 given, 6 used, 2 rejected" in run.stdout
    assert run.stdout.count("not one moment") == 2 and "L02.png + R02.png: not one moment" in run.stdout
    assert np.linalg.norm(load_calibration(str(tmp_path / "c.json")).T) == pytest.approx(80.0, rel=0.005)


def test_views_that_fit_no_rig_are_refused_in_one_line(rendered, tmp_path):
    folder = tmp_path / "mirrored"
    folder.mkdir()
    for f in rendered.glob("L*.png"):
        (folder / f.name).write_bytes(f.read_bytes())
        cv2.imwrite(str(folder / f.name.replace("L", "R")), cv2.imread(str(f))[:, ::-1])
    run = fishfarm(*args(folder, tmp_path / "c.json"))
    assert_bad_input(run, "rig")
    assert "()" not in run.stderr and not (tmp_path / "c.json").exists()
