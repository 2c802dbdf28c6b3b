"""``fishfarm calibrate ... --out -``: the calibration alone on the standard output, whole, and the
command's report on the standard error (it was printed into the JSON: ``--out - | jq`` failed), run
as the user runs it (a subprocess, its output in a pipe or appended to a log)."""
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from devices.sim.stereo_rig import measure_grid
from devices.sim.stereo_scene import board_session
from tests.controller.test_cli_calibrate_dlt import GRID_HEADER, RIG, WORLD, write_csv
from tests.controller.test_cli_calibrate_import_p34 import calib_json
from tests.controller.test_cli_calibrate_tower import POND, ref_text

FISHFARM = str(Path(sys.executable).parent / "fishfarm")


def _dlt(tmp_path):
    grid = measure_grid(RIG, WORLD, 0.2, np.random.default_rng(21))
    path = write_csv(tmp_path / "GRID.csv", GRID_HEADER, grid.tolist())
    return ["calibrate", "dlt", "--points", path], {"P1", "P2"}, "reprojection RMS"


def _tower(tmp_path):
    path = tmp_path / "REF.csv"
    path.write_text(ref_text(POND))
    return ["calibrate", "tower", "--points", path], {"H", "rms_m"}, "error on the pond RMS"


def _import(tmp_path):
    path = tmp_path / "cb.json"
    path.write_text(json.dumps(calib_json()))
    return ["calibrate", "import", "--in", path], {"P1", "P2", "D1"}, "D1/D2 kept"


def _chessboard(tmp_path):
    for i, (a, b) in enumerate(board_session(4, np.random.default_rng(3)).pairs):
        cv2.imwrite(str(tmp_path / f"L{i:02d}.png"), a)
        cv2.imwrite(str(tmp_path / f"R{i:02d}.png"), b)
    return (["calibrate", "chessboard", "--left", tmp_path / "L*.png", "--right", tmp_path / "R*.png",
             "--square-mm", "25"], {"P1", "P2", "pairs_used"}, "RMS reprojection error")


COMMANDS = {"dlt": _dlt, "tower": _tower, "import": _import, "chessboard": _chessboard}


@pytest.mark.parametrize("name", sorted(COMMANDS))
@pytest.mark.parametrize("out", ["-", "/dev/stdout"])
def test_the_calibration_alone_on_the_standard_output_and_the_report_on_the_standard_error(tmp_path, name, out):
    args, fields, said = COMMANDS[name](tmp_path)
    done = subprocess.run([FISHFARM, *map(str, args), "--out", out], capture_output=True, text=True, timeout=60,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout)                          # the whole of it, nothing else
    assert fields <= set(doc)
    assert said in done.stderr and done.stderr.rstrip().endswith(out)     # "written: -" / "wrote -" last
    assert not [p.name for p in tmp_path.iterdir() if p.name == "-" or p.name.endswith(".part")]


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_appended_to_a_log_the_log_keeps_what_it_had(tmp_path, name):
    args, fields, said = COMMANDS[name](tmp_path)
    log = tmp_path / "calibrations.log"
    log.write_text("yesterday's\n")
    with open(log, "a") as fh:
        done = subprocess.run([FISHFARM, *map(str, args), "--out", "-"], stdout=fh, stderr=subprocess.PIPE,
                              text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    text = log.read_text()
    assert text.startswith("yesterday's\n") and fields <= set(json.loads(text[len("yesterday's\n"):]))
    assert said in done.stderr
