"""``fishfarm track`` on a clip drawn from the contracts (frames.csv, TOWER.json, the float marker):
one run as the user runs it (a subprocess), and every bad input refused with one line naming the
file and the fault, nothing written."""
import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from controller.cli import main
from tests.controller.huge_images import huge_png
from tests.vision import float_drawing as fd

FISHFARM = str(Path(sys.executable).parent / "fishfarm")
VIEW = fd.view(640, 360, hfov_deg=75.0)          # not the usual frame size
FPS = 8.0                                          # nor the usual rate


def pose(t):
    return 6.0 + 0.4 * t, 4.0 + 0.1 * t, 0.25


def write_clip(d: Path, n=16, hidden=(8, 9, 10), start=5000.0) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    rows = ["frame,t_s,file"]
    for i in range(n):
        t = i / FPS
        img = fd.frame(VIEW, None if i in hidden else pose(t), seed=i)
        cv2.imwrite(str(d / f"f{i:03d}.png"), img)
        rows.append(f"{i},{start + t!r},f{i:03d}.png")
    (d / "frames.csv").write_text("\n".join(rows) + "\n")
    (d / "tower.json").write_text(json.dumps({"H": VIEW.H.tolist()}))
    return d


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_clip(tmp_path_factory.mktemp("clip"))


def test_replays_the_clip_one_entry_a_frame(clip, tmp_path):
    out = tmp_path / "OUT.json"
    result = subprocess.run([FISHFARM, "track", "--frames", clip, "--tower", clip / "tower.json", "--json", out],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    track = json.loads(out.read_text())["track"]
    assert len(track) == 16 and [e["frame"] for e in track] == list(range(16))
    for i, e in enumerate(track):
        t = i / FPS
        assert e["t_s"] == 5000.0 + t
        x, y, h = pose(t)
        if i in (8, 9, 10):
            assert e["state"] == "predicted" and e["confidence"] is None
            assert math.hypot(e["x_m"] - x, e["y_m"] - y) < 0.1
        else:
            assert e["state"] == "tracking" and 0 < e["confidence"] <= 1
            assert math.hypot(e["x_m"] - x, e["y_m"] - y) < 0.03
            assert abs(math.remainder(e["heading_rad"] - h, 2 * math.pi)) < math.radians(3)
    assert "16 frames: tracking 13, predicted 3, lost 0" in result.stdout


def test_json_dash_is_the_standard_output_and_the_summary_moves_to_stderr(clip, tmp_path):
    result = subprocess.run([FISHFARM, "track", "--frames", clip, "--tower", clip / "tower.json", "--json", "-"],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert len(json.loads(result.stdout)["track"]) == 16       # stdout is the JSON alone, whole
    assert "16 frames: tracking 13" in result.stderr
    assert list(tmp_path.iterdir()) == []                       # no file named '-'


def test_a_long_gap_is_lost_with_null_position(tmp_path):
    d = write_clip(tmp_path / "c", n=14, hidden=set(range(4, 10)))
    out = tmp_path / "OUT.json"
    assert main(["track", "--frames", str(d), "--tower", str(d / "tower.json"), "--json", str(out),
                 "--lost-after", "0.5"]) == 0
    states = [e["state"] for e in json.loads(out.read_text())["track"]]
    assert states[:4] == ["tracking"] * 4 and states[10:] == ["tracking"] * 4
    assert "lost" in states[4:10] and states[4] == "predicted"
    lost = [e for e in json.loads(out.read_text())["track"] if e["state"] == "lost"]
    assert all(e["x_m"] is None and e["y_m"] is None and e["heading_rad"] is None for e in lost)


def refused(capsys, args, where, fault, out):
    rc = main(["track", *map(str, args)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"fishfarm: {where}") and fault in err, err
    assert not out.exists()


@pytest.mark.parametrize("text, fault", [
    ("{not json", "not JSON"),
    ('{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}', "H: missing"),
    ('[[1, 0, 0], [0, 1, 0], [0, 0, 1]]', "H: missing"),
    ('{"H": [[1, 0, 0], [0, 1, 0]]}', "H: expected a 3x3 array of numbers, got shape (2, 3)"),
    ('{"H": [[1, 0, 0], [0, 1, 0], [0, 0]]}', "H: expected a 3x3 array of numbers"),
    ('{"H": [[1, 0, "a"], [0, 1, 0], [0, 0, 1]]}', "H: expected a 3x3 array of numbers"),
    ('{"H": [[1, 0, "1.0"], [0, 1, 0], [0, 0, 1]]}', "H: expected a 3x3 array of numbers"),   # numpy reads it
    ('{"H": [[true, 0, 0], [0, 1, 0], [0, 0, 1]]}', "H: expected a 3x3 array of numbers"),
    ('{"H": [[1, 0, NaN], [0, 1, 0], [0, 0, 1]]}', "H: a value is not a finite number"),
    ('{"H": [[1, 0, Infinity], [0, 1, 0], [0, 0, 1]]}', "H: a value is not a finite number"),
    ('{"H": [[1, 2, 3], [2, 4, 6], [0, 0, 1]]}', "H: singular"),
    ('{"H": [[0, 0, 0], [0, 0, 0], [0, 0, 0]]}', "H: singular"),
])
def test_a_tower_file_that_is_not_a_homography_exits_2(capsys, clip, tmp_path, text, fault):
    tower = tmp_path / "TOWER.json"
    tower.write_text(text)
    out = tmp_path / "OUT.json"
    refused(capsys, ["--frames", clip, "--tower", tower, "--json", out], tower, fault, out)


@pytest.mark.parametrize("scale", [1e-120, 1e120, -1.0])
def test_a_homography_at_any_scale_is_the_same_homography(clip, tmp_path, capsys, scale):
    """H is defined up to scale: 1e120 x H tracks as H (it overflowed into 'singular' with numpy's
    warnings on stderr)."""
    H = np.array(json.loads((clip / "tower.json").read_text())["H"], float)
    tower = tmp_path / "scaled.json"
    tower.write_text(json.dumps({"H": (H * scale).tolist()}))
    outs = []
    for name, t in (("a", clip / "tower.json"), ("b", tower)):
        assert main(["track", "--frames", str(clip), "--tower", str(t), "--json", str(tmp_path / f"{name}.json")]) == 0
        outs.append(json.loads((tmp_path / f"{name}.json").read_text())["track"])
    assert capsys.readouterr().err == ""
    for a, b in zip(*outs, strict=True):
        assert a["state"] == b["state"]
        if a["x_m"] is not None:
            assert (a["x_m"], a["y_m"]) == pytest.approx((b["x_m"], b["y_m"]), abs=1e-9)


def test_missing_tower_file_and_folder(capsys, clip, tmp_path):
    out = tmp_path / "OUT.json"
    refused(capsys, ["--frames", clip, "--tower", tmp_path / "no.json", "--json", out],
            tmp_path / "no.json", "no such file", out)
    refused(capsys, ["--frames", tmp_path / "nodir", "--tower", clip / "tower.json", "--json", out],
            tmp_path / "nodir", "no such directory", out)
    empty = tmp_path / "empty"
    empty.mkdir()
    refused(capsys, ["--frames", empty, "--tower", clip / "tower.json", "--json", out],
            empty / "frames.csv", "no such file", out)


@pytest.mark.parametrize("body, fault", [
    ("", "empty file"),
    ("frame,time,file\n0,0.0,f000.png\n", "header: expected 'frame,t_s,file', found 'frame,time,file'"),
    ("frame,t_s,file\n0,0.0,f000.png\n1,abc,f001.png\n", "line 3, column t_s: not a number: 'abc'"),
    ("frame,t_s,file\n0,0.0,f000.png\n1,inf,f001.png\n", "line 3, column t_s: inf is not a finite number"),
    ("frame,t_s,file\n0,0.0,f000.png\n1.5,0.1,f001.png\n", "line 3, column frame: not a frame number: '1.5'"),
    ("frame,t_s,file\n-1,0.0,f000.png\n", "line 2, column frame: not a frame number: '-1'"),
    ("frame,t_s,file\n0,1.0,f000.png\n1,0.5,f001.png\n", "line 3, column t_s: 0.5 is earlier than the row before"),
    # the Kalman step to the 4th power overflowed (an internal error, exit 1) from ~1e77
    ("frame,t_s,file\n0,0,f000.png\n1,1e155,f001.png\n", "line 3, column t_s: 1e155: beyond 1e+11 s"),
    ("frame,t_s,file\n0,-2e11,f000.png\n1,0,f001.png\n", "line 2, column t_s: -2e11: beyond 1e+11 s"),
    ("frame,t_s,file\n0,0.0,f000.png\n1,0.1\n", "line 3: 2 fields, expected 3"),
    ("frame,t_s,file\n0,0.0,f000.png\n1,0.1, \n", "line 3, column file: empty"),
    ("frame,t_s,file\n7,0.0,f000.png\n8,0.1,f001.png\n7,0.2,f001.png\n",
     "line 4, column frame: frame 7 again (line 2)"),
    # a NUL in a name was a ValueError (exit 1, "internal error")
    ("frame,t_s,file\n0,0.0,f\x000.png\n", "line 2, column file: unprintable character '\\x00' in 'f\\x000.png'"),
    ("frame,t_s,file\n0,0.0,f000.png\n1,0.1,f\x1b[2Jx.png\n", "line 3, column file: unprintable character '\\x1b'"),
    ("frame,t_s,file\n0,0.0,f000.png\n1e300,0.1,f001.png\n", "line 3, column frame: not a frame number: '1e300'"),
    ("frame,t_s,file\n++5,0.0,f000.png\n", "line 2, column frame: not a number: '++5'"),
    # digits read as an integer; only whole numbers a float holds exactly otherwise
    ("frame,t_s,file\n0,0.0,f000.png\n99999999999999999999999,0.1,f001.png\n12,0.2,f001.png\n"
     "99999999999999999999999,0.3,f000.png\n", "line 5, column frame: frame 99999999999999999999999 again (line 3)"),
])
def test_a_malformed_frames_csv_is_named_by_line_and_column(capsys, clip, tmp_path, body, fault):
    d = tmp_path / "clip"
    d.mkdir()
    for name in ("f000.png", "f001.png"):
        (d / name).write_bytes((clip / name).read_bytes())
    (d / "frames.csv").write_text(body)
    out = tmp_path / "OUT.json"
    refused(capsys, ["--frames", d, "--tower", clip / "tower.json", "--json", out], d / "frames.csv", fault, out)


def test_frame_numbers_come_back_exactly_as_written(clip, tmp_path):
    d = tmp_path / "clip"
    d.mkdir()
    for name in ("f000.png", "f001.png"):
        (d / name).write_bytes((clip / name).read_bytes())
    big = 10 ** 23 - 1                       # as a float: 99999999999999991611392
    (d / "frames.csv").write_text(f"frame,t_s,file\n{big},0.0,f000.png\n+7,0.1,f001.png\n8.0,0.2,f001.png\n")
    out = tmp_path / "OUT.json"
    result = subprocess.run([FISHFARM, "track", "--frames", d, "--tower", clip / "tower.json", "--json", out],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert [e["frame"] for e in json.loads(out.read_text())["track"]] == [big, 7, 8]


def test_an_unreadable_or_missing_frame_exits_2_naming_it(capsys, clip, tmp_path):
    d = tmp_path / "clip"
    d.mkdir()
    (d / "f000.png").write_bytes((clip / "f000.png").read_bytes())
    (d / "f001.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really a png")
    (d / "frames.csv").write_text("frame,t_s,file\n0,0.0,f000.png\n1,0.1,f001.png\n2,0.2,f002.png\n")
    out = tmp_path / "OUT.json"
    refused(capsys, ["--frames", d, "--tower", clip / "tower.json", "--json", out], d / "f001.png",
            f"cannot read it as an image ({d / 'frames.csv'} line 3)", out)
    (d / "f001.png").write_bytes((clip / "f001.png").read_bytes())
    refused(capsys, ["--frames", d, "--tower", clip / "tower.json", "--json", out], d / "f002.png",
            f"no such file ({d / 'frames.csv'} line 4)", out)


def test_a_frame_declaring_more_pixels_than_opencv_reads_exits_2_naming_it(capsys, clip, tmp_path):
    d = tmp_path / "clip"
    d.mkdir()
    (d / "f000.png").write_bytes(huge_png())
    (d / "frames.csv").write_text("frame,t_s,file\n0,0.0,f000.png\n")
    out = tmp_path / "OUT.json"
    refused(capsys, ["--frames", d, "--tower", clip / "tower.json", "--json", out], d / "f000.png",
            "too large: over 2^30 pixels", out)


def test_frames_of_another_size_in_one_clip_and_an_empty_clip(capsys, clip, tmp_path):
    d = tmp_path / "clip"
    d.mkdir()
    big = fd.view(1024, 576, hfov_deg=75.0)
    cv2.imwrite(str(d / "a.png"), fd.frame(VIEW, pose(0.0)))
    cv2.imwrite(str(d / "b.png"), fd.frame(big, pose(0.1)))
    (d / "frames.csv").write_text("frame,t_s,file\n0,0.0,a.png\n1,0.1,b.png\n")
    out = tmp_path / "OUT.json"
    # one H for both: the second frame's float is elsewhere in pixels, so found elsewhere on the pond
    assert main(["track", "--frames", str(d), "--tower", str(clip / "tower.json"), "--json", str(out)]) == 0
    assert len(json.loads(out.read_text())["track"]) == 2
    (d / "frames.csv").write_text("frame,t_s,file\n")
    assert main(["track", "--frames", str(d), "--tower", str(clip / "tower.json"), "--json", str(out)]) == 0
    assert json.loads(out.read_text()) == {"track": []}
    np.testing.assert_equal(capsys.readouterr().err, "")


def test_frames_of_another_size_than_tower_json_was_fitted_to_are_refused(tmp_path, capsys):
    d = write_clip(tmp_path / "c", n=3, hidden=())
    (d / "tower.json").write_text(json.dumps({"H": VIEW.H.tolist(), "image_size": [1280, 720]}))
    refused(capsys, ["--frames", d, "--tower", d / "tower.json", "--json", tmp_path / "o.json"],
            d / "f000.png", "640x360, but TOWER.json was fitted to 1280x720", tmp_path / "o.json")
    (d / "tower.json").write_text(json.dumps({"H": VIEW.H.tolist(), "image_size": [640, 360]}))
    ok = ["track", "--frames", str(d), "--tower", str(d / "tower.json"), "--json", str(tmp_path / "o.json")]
    assert main(ok) == 0
    (d / "tower.json").write_text(json.dumps({"H": VIEW.H.tolist(), "image_size": [640.5, True]}))
    refused(capsys, ["--frames", d, "--tower", d / "tower.json", "--json", tmp_path / "o2.json"],
            d / "tower.json", "image_size", tmp_path / "o2.json")


@pytest.mark.parametrize("kind", ["grey", "grey as colour"])
def test_a_grey_frame_is_refused_not_read_as_no_float(tmp_path, capsys, kind):
    d = write_clip(tmp_path / "c", n=3, hidden=())
    grey = cv2.cvtColor(cv2.imread(str(d / "f001.png")), cv2.COLOR_BGR2GRAY)
    cv2.imwrite(str(d / "f001.png"), grey if kind == "grey" else cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    refused(capsys, ["--frames", d, "--tower", d / "tower.json", "--json", tmp_path / "o.json"],
            d / "f001.png", "a grey picture", tmp_path / "o.json")
