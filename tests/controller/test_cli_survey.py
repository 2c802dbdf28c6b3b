"""``fishfarm survey`` as outside scripts run it: a subprocess, images in, OUT.json out. The per-pair
pipeline is a stand-in (hidden --measure) reading fish drawn as dots at their true projections."""
import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from devices.sim.stereo_rig import convergent_rig
from tests.controller.huge_images import huge_jpeg, huge_png
from tests.controller.surveys import standin

ROOT = Path(__file__).resolve().parents[2]
FISHFARM = str(Path(sys.executable).parent / "fishfarm")
DOTS = "tests.controller.surveys.standin:dots"


def run(*args, measure=DOTS):
    extra = ["--measure", measure] if measure else []
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([FISHFARM, "survey", *map(str, args), *extra], capture_output=True, text=True,
                          timeout=120, env=env)


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    d = tmp_path_factory.mktemp("survey")
    rig = convergent_rig()
    (d / "calib.json").write_text(json.dumps(rig.calibration().to_json()))
    rng = np.random.default_rng(11)
    truth = []
    (d / "pairs").mkdir()
    for i, n in enumerate([2, 3, 0, 1]):
        fish = standin.random_fish(rig, rng, n)
        left, right = standin.draw_fish(rig, fish, colour=i % 2 == 1)
        cv2.imwrite(str(d / "pairs" / f"p{i}_L.png"), left)
        cv2.imwrite(str(d / "pairs" / f"p{i}_R.png"), right)
        # the paper's grabber: left in red, right in green, blue empty
        g = lambda im: im if im.ndim == 2 else cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)  # noqa: E731
        cv2.imwrite(str(d / f"rg{i}.png"), np.dstack([np.zeros_like(g(left)), g(right), g(left)]))
        truth.append(sorted(np.linalg.norm(s - f) / 10 for s, f in fish))
    return d, truth


def common(d, *rest):
    return ["--calib", d / "calib.json", "--species", "sparus_aurata", "--setup", "underwater", *rest]


def test_a_directory_survey_end_to_end(farm):
    d, truth = farm
    r = run(*common(d, "--dir", d / "pairs", "--json", d / "out.json", "--csv", d / "fish.csv",
                    "--plot", d / "hist.png", "--workers", "2", "--up", "0,0,5"))
    assert r.returncode == 0, r.stderr
    doc = json.loads((d / "out.json").read_text())
    assert (doc["species"], doc["setup"], doc["frames"], doc["count"]) == ("sparus_aurata", "underwater", 4, 6)
    for frame, lengths in enumerate(truth):
        assert sorted(f["length_cm"] for f in doc["fish"] if f["frame"] == frame) == pytest.approx(lengths, rel=0.01)
    assert sum(doc["length_cm"]["histogram"]["counts"]) == 6 == sum(doc["weight_g"]["histogram"]["counts"])
    lo, hi = doc["weight_g"]["ci"]
    assert lo <= doc["weight_g"]["mean"] <= hi
    assert len((d / "fish.csv").read_text().splitlines()) == 7
    img = cv2.imread(str(d / "hist.png"))
    assert img is not None and img.shape[1] > 800
    assert r.stderr.strip().startswith("6 fish in 4 pairs: mean weight")   # no progress bar in a pipe


def test_a_pair_copied_into_the_directory_is_surveyed_once_and_said(farm, tmp_path):
    import shutil
    d, truth = farm
    shutil.copytree(d / "pairs", tmp_path / "pairs")
    for side in "LR":
        shutil.copy(d / "pairs" / f"p1_{side}.png", tmp_path / "pairs" / f"p1 copy_{side}.png")
    r = run(*common(d, "--dir", tmp_path / "pairs", "--json", tmp_path / "out.json", "--workers", "1"))
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "out.json").read_text())
    assert (doc["frames"], doc["count"]) == (4, sum(map(len, truth)))
    [said] = [line for line in r.stderr.splitlines() if "the same images" in line]
    assert said.startswith("fishfarm survey: warning: ") and "p1 copy_L.png" in said and "p1_L.png" in said


@pytest.fixture(scope="module")
def textured(tmp_path_factory):
    """Three surface pairs (a textured tank floor) and their rig's calibration, and another rig's."""
    from devices.sim.fish_scene import surface_rig, surface_scene
    d = tmp_path_factory.mktemp("textured")
    rig = surface_rig()
    rng = np.random.default_rng(4)
    for i in range(3):
        scene = surface_scene(rng, rig=rig, n_fish=6)
        cv2.imwrite(str(d / f"s{i}_L.png"), scene.left)
        cv2.imwrite(str(d / f"s{i}_R.png"), scene.right)
    (d / "calib.json").write_text(json.dumps(rig.calibration().to_json()))
    (d / "other.json").write_text(json.dumps(convergent_rig(baseline_mm=300, crossing_mm=900).calibration().to_json()))
    return d


@pytest.mark.parametrize("views,calib,said", [("given", "calib.json", None),
                                              ("swapped", "calib.json", "look swapped"),
                                              ("given", "other.json", "do not fit the calibration")])
def test_a_survey_without_fish_says_when_its_views_are_swapped_or_its_calibration_another_rig_s(
        textured, tmp_path, views, calib, said):
    d = textured
    order = (lambda i: [d / f"s{i}_L.png", d / f"s{i}_R.png"]) if views == "given" else \
        (lambda i: [d / f"s{i}_R.png", d / f"s{i}_L.png"])
    args = ["--calib", d / calib, "--species", "sparus_aurata", "--setup", "surface", "--json", tmp_path / "o.json",
            *sum((["--pair", *order(i)] for i in range(3)), [])]
    r = run(*args, measure="tests.controller.surveys.standin:no_fish")
    assert r.returncode == 0, r.stderr
    warned = [line for line in r.stderr.splitlines() if "no fish in any pair" in line]
    if said is None:
        assert warned == [], r.stderr
    else:
        assert len(warned) == 1 and said in warned[0] and warned[0].startswith("fishfarm survey: warning:"), r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("0 fish in 3 pairs")


def test_rg_frames_give_the_same_fish_as_the_pairs(farm):
    d, truth = farm
    r = run(*common(d, *sum((["--rg", d / f"rg{i}.png"] for i in range(4)), []), "--json", d / "rg.json",
                    "--config", "config/farm.toml", "--stock", "nursery", "--workers", "1"))
    assert r.returncode == 0, r.stderr
    doc = json.loads((d / "rg.json").read_text())
    assert sorted(f["length_cm"] for f in doc["fish"]) == pytest.approx(sorted(sum(truth, [])), rel=0.01)
    assert doc["coefficients"]["a"] == 0.012
    f = doc["fish"][0]
    assert f["weight_g"] == pytest.approx(0.012 * f["length_cm"] ** 3.032, rel=1e-3)


def test_no_fish_is_an_empty_survey_not_an_error(farm):
    d, _ = farm
    r = run(*common(d, "--pair", d / "pairs/p2_L.png", d / "pairs/p2_R.png", "--json", d / "empty.json"))
    assert r.returncode == 0, r.stderr
    doc = json.loads((d / "empty.json").read_text())
    assert doc["count"] == 0 and doc["fish"] == [] and doc["weight_g"]["mean"] is None


def make_mp4(path, frame, n):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (frame.shape[1], frame.shape[0]))
    for _ in range(n):
        writer.write(frame)
    writer.release()
    return path


def one_line_exit_2(r, *words):
    assert r.returncode == 2, (r.returncode, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_unknown_species_lists_the_known_ones(farm):
    d, _ = farm
    r = run("--calib", d / "calib.json", "--species", "tuna", "--setup", "surface", "--dir", d / "pairs",
            "--json", d / "x.json")
    one_line_exit_2(r, "--species", "unknown species 'tuna'", "sparus_aurata", "salmo_salar")


@pytest.mark.parametrize("option, value", [("--seed", "-1"), ("--every", "0"), ("--max-frames", "-3"),
                                           ("--workers", "0"), ("--up", "0,0,0"), ("--up", "nan,0,1"),
                                           ("--floor-mm", "0"), ("--floor-mm", "inf"), ("--floor-mm", "-5")])
def test_out_of_range_options_exit_2_naming_the_option(farm, option, value):
    d, _ = farm
    r = run(*common(d, "--dir", d / "pairs", "--json", d / "x.json", option, value))
    one_line_exit_2(r, option, value)


def test_a_sync_offset_for_anything_but_two_videos_exits_2(farm):
    d, _ = farm
    r = run(*common(d, "--dir", d / "pairs", "--json", d / "x.json", "--sync-offset", "2"))
    one_line_exit_2(r, "--sync-offset", "is for two videos (--video LEFT RIGHT)")
    assert not (d / "x.json").exists()


def test_pairs_of_different_sizes(farm, tmp_path):
    d, _ = farm
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((480, 640), np.uint8))
    r = run(*common(d, "--pair", d / "pairs/p0_L.png", small, "--json", tmp_path / "x.json"))
    one_line_exit_2(r, str(small), "640x480 pixels, but the left image", "1280x960")
    assert not (tmp_path / "x.json").exists()


def test_calibration_made_for_another_image_size(farm, tmp_path):
    d, _ = farm
    calib = json.loads((d / "calib.json").read_text())
    calib["image_size"] = [1920, 1080]
    (tmp_path / "c.json").write_text(json.dumps(calib))
    r = run("--calib", tmp_path / "c.json", "--species", "sparus_aurata", "--setup", "underwater",
            "--rg", d / "rg0.png", "--json", tmp_path / "x.json")
    one_line_exit_2(r, "rg0.png", "image_size: calibration made for 1920x1080 images, the frames are 1280x960")


def test_missing_files_and_empty_directories(farm, tmp_path):
    d, _ = farm
    one_line_exit_2(run(*common(d, "--pair", d / "pairs/p0_L.png", tmp_path / "gone.png", "--json",
                                tmp_path / "x.json")), "gone.png: no such file")
    one_line_exit_2(run(*common(d, "--dir", tmp_path, "--json", tmp_path / "x.json")),
                    f"{tmp_path}: no pairs")
    one_line_exit_2(run("--calib", tmp_path / "none.json", "--species", "sparus_aurata", "--setup", "underwater",
                        "--dir", d / "pairs", "--json", tmp_path / "x.json"), "none.json: no such file")
    one_line_exit_2(run(*common(d, "--json", tmp_path / "x.json")), "give exactly one input")


@pytest.mark.parametrize("option", ["--json", "--csv", "--plot"])
def test_an_output_that_is_a_directory_another_output_or_an_input_is_refused_before_the_survey(farm, tmp_path,
                                                                                                option):
    d, _ = farm
    calib, left = tmp_path / "calib.json", tmp_path / "p_L.png"
    calib.write_bytes((d / "calib.json").read_bytes())
    left.write_bytes((d / "pairs/p0_L.png").read_bytes())
    before = {p: p.read_bytes() for p in (calib, left)}
    outputs = {"--json": tmp_path / "out.json", "--csv": tmp_path / "fish.csv", "--plot": tmp_path / "hist.png"}
    (tmp_path / "a_dir").mkdir()
    other = next(o for o in outputs if o != option)
    clashes = [(tmp_path / "a_dir", [f"a_dir: {option}: a directory, not a file"]),
               # either option may be named first
               (tmp_path / "." / outputs[other].name, [outputs[other].name, ": the same file as --", option, other]),
               (calib, [f"calib.json: {option}: an input of this command"]),
               (left, [f"p_L.png: {option}: an input of this command"])]
    for path, words in clashes:
        given = {**outputs, option: path}
        r = run("--calib", calib, "--species", "sparus_aurata", "--setup", "underwater",
                "--pair", left, d / "pairs/p0_R.png", *(x for o in given.items() for x in o))
        one_line_exit_2(r, *words)
        assert {p: p.read_bytes() for p in (calib, left)} == before
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a_dir", "calib.json", "p_L.png"]


def test_a_file_that_is_no_video_is_one_line_without_ffmpegs_own_complaint(farm, tmp_path):
    # FFmpeg prints "moov atom not found" for a broken mp4 unless told not to
    d, _ = farm
    left = make_mp4(tmp_path / "left.mp4", cv2.imread(str(d / "pairs/p0_L.png")), 3)
    broken = tmp_path / "right.mp4"
    broken.write_bytes(Path(left).read_bytes()[:40])
    one_line_exit_2(run(*common(d, "--video", left, broken, "--json", tmp_path / "x.json")),
                    "right.mp4: cannot open as a video")


def test_a_still_declaring_more_pixels_than_opencv_reads_is_one_line(farm, tmp_path):
    d, _ = farm
    (tmp_path / "huge.png").write_bytes(huge_png())
    (tmp_path / "huge.jpg").write_bytes(huge_jpeg())
    for name in ("huge.png", "huge.jpg"):
        # (refused from its header, before OpenCV would refuse its 2^30 pixels)
        one_line_exit_2(run(*common(d, "--pair", tmp_path / name, d / "pairs/p0_R.png", "--json", tmp_path / "x.json")),
                        f"{name}: ", "pixels: more than any survey camera's 50 megapixels")


def test_a_still_its_codec_reports_damaged_is_one_line_not_a_survey_of_the_smear(farm, tmp_path):
    """A JPEG with 64 bytes zeroed mid-scan: OpenCV decodes it (libjpeg's note on stderr) and the
    survey measured the smear; a 16-bit PNG with a CRC error: libpng's line beside ours."""
    d, _ = farm
    left = cv2.imread(str(d / "pairs/p0_L.png"))
    jpg = bytearray(cv2.imencode(".jpg", left, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes())
    jpg[len(jpg) // 2:len(jpg) // 2 + 64] = bytes(64)
    (tmp_path / "mid.jpg").write_bytes(bytes(jpg))
    png = bytearray(cv2.imencode(".png", left.astype(np.uint16) * 257)[1].tobytes())
    png[len(png) // 2] ^= 0xFF
    (tmp_path / "crc16.png").write_bytes(bytes(png))
    for name, said in (("mid.jpg", "damaged image (its decoder: Corrupt JPEG data"),
                       ("crc16.png", "its decoder: libpng error: IDAT")):
        got = run(*common(d, "--pair", tmp_path / name, d / "pairs/p0_R.png", "--json", tmp_path / "x.json"))
        one_line_exit_2(got, f"{name}: ")
        assert said in got.stderr, got.stderr


def test_without_the_pipeline_merged_it_says_so_in_one_line(farm, tmp_path):
    """Until vision.underwater lands, the real command fails as an internal error, not as bad input."""
    d, _ = farm
    r = run(*common(d, "--rg", d / "rg2.png", "--json", tmp_path / "x.json"), measure=None)
    try:
        import vision.underwater  # noqa: F401
    except ModuleNotFoundError:
        assert r.returncode == 1 and "vision.underwater" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    else:
        assert r.returncode == 0, r.stderr


def test_a_progress_bar_on_a_terminal_none_in_a_pipe_and_a_faint_blue_channel_warned_once(farm, tmp_path):
    import pty
    d, _ = farm
    frames = []
    for i in range(3):
        img = cv2.imread(str(d / f"rg{i}.png"))
        img[..., 0] = 40                                  # blue bleeding in, as from a JPEG grabber
        cv2.imwrite(str(tmp_path / f"[b]{i}.png"), img)   # brackets: not rich markup
        frames += ["--rg", tmp_path / f"[b]{i}.png"]
    args = common(d, *frames, "--json", tmp_path / "o.json")
    r = run(*args)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines[0] == (f"fishfarm survey: warning: {tmp_path}/[b]0.png: blue channel not empty (mean level 40): "
                        "is this an RG frame? using red = left, green = right")
    assert lines[1] == "fishfarm survey: warning: the same for 2 more pairs" and len(lines) == 3
    master, slave = pty.openpty()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "100"}
    p = subprocess.run([FISHFARM, "survey", *map(str, args), "--measure", DOTS], stdout=subprocess.DEVNULL,
                       stderr=slave, env=env, timeout=120)
    os.close(slave)
    out = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
    os.close(master)
    assert p.returncode == 0
    text = out.decode(errors="replace")
    assert "survey" in text and "3/3" in text and f"{tmp_path}/[b]0.png: blue channel" in text


def _farm_toml(tmp_path):
    """The demo's farm.toml with its ledger in ``tmp_path``: (its path, the config as read)."""
    import tomllib

    import tomli_w
    raw = tomllib.loads((ROOT / "config" / "farm.toml").read_text())
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    return tmp_path / "farm.toml", raw


def test_a_survey_recorded_for_a_tank_sets_its_ration(farm, tmp_path):
    import tomli_w

    from controller.config import load_config
    from controller.feeding.rations import Rations, load_species
    from controller.store import Store
    d, truth = farm
    cfg_path, raw = _farm_toml(tmp_path)
    r = run(*common(d, "--dir", d / "pairs", "--json", tmp_path / "out.json", "--config", cfg_path, "--tank", "T2"))
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "out.json").read_text())
    store = Store(tmp_path / "ledger.db")
    [s] = store.surveys("T2")
    assert s.count == doc["count"] == 6 and s.source == str(tmp_path / "out.json")
    assert s.mean_weight_g == pytest.approx(doc["weight_g"]["mean"], rel=1e-6)
    # every fish's score kept beside its length (history/fish and `fishfarm history` read it)
    rows = store.db.execute("SELECT length_cm, score FROM survey_fish WHERE survey = ? ORDER BY rowid",
                            (s.id,)).fetchall()
    assert [(round(a, 3), round(b, 4)) for a, b in rows] == [(f["length_cm"], f["score"]) for f in doc["fish"]]
    rations = Rations(load_config(str(cfg_path)), load_species(), store)
    assert rations.plan("T2", s.t + 60).source == "survey"
    # refused before anything is measured: another species' tank, a tank that is not there
    for tank, fault in (("T9", "--tank: no tank 'T9'"),):
        bad = run(*common(d, "--dir", d / "pairs", "--json", tmp_path / "x.json", "--config", cfg_path, "--tank", tank))
        assert bad.returncode == 2 and fault in bad.stderr and not (tmp_path / "x.json").exists()
    raw["tanks"][0]["species"] = "dicentrarchus_labrax"
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    bad = run(*common(d, "--dir", d / "pairs", "--json", tmp_path / "y.json", "--config", cfg_path, "--tank", "T1"))
    assert bad.returncode == 2 and "T1 holds dicentrarchus_labrax, not sparus_aurata" in bad.stderr


def test_a_recorded_survey_is_stamped_with_the_farm_s_time_and_an_emptied_tank_refused(farm, tmp_path):
    """A controller on a sped-up clock writes the ledger ahead of the wall: a survey stamped with the
    wall's time landed 18 farm hours back, before the stock events it follows. A tank whose stock
    events took all its fish is refused before anything is measured, as start-survey refuses it."""
    import time

    from controller.store import Store
    d, _ = farm
    cfg_path, raw = _farm_toml(tmp_path)
    ahead = time.time() + 30 * 86400.0                   # where a farm at --speed 600 may be
    store = Store(tmp_path / "ledger.db")
    store.add_stock_event(t=ahead, tank="T3", kind="mortality", count=5, to_tank=None, who="t")
    store.add_stock_event(t=ahead, tank="T4", kind="harvest", count=raw["tanks"][3]["stock"], to_tank=None, who="t")
    store.close()
    ok = run(*common(d, "--dir", d / "pairs", "--json", tmp_path / "a.json", "--config", cfg_path, "--tank", "T3"))
    assert ok.returncode == 0, ok.stderr
    bad = run(*common(d, "--dir", d / "pairs", "--json", tmp_path / "b.json", "--config", cfg_path, "--tank", "T4"))
    one_line_exit_2(bad, "--tank", "T4 holds no fish")
    assert not (tmp_path / "b.json").exists()
    store = Store(tmp_path / "ledger.db")
    [s] = store.surveys("T3")
    assert ahead <= s.t < ahead + 60 and store.surveys("T4") == []
    store.close()


def test_the_same_fish_recorded_again_is_refused(farm, tmp_path):
    """The same pairs surveyed twice made two identical surveys, counted twice by the growth fit
    (an SGR of -0.00 ± 454,543 %/day over 0.0 days in the report)."""
    from controller.store import Store
    d, _ = farm
    cfg = ("--config", _farm_toml(tmp_path)[0], "--tank", "T2")
    first = run(*common(d, "--dir", d / "pairs", "--json", tmp_path / "a.json", *cfg))
    assert first.returncode == 0, first.stderr
    again = run(*common(d, "--dir", d / "pairs", "--json", tmp_path / "b.json", *cfg))
    one_line_exit_2(again, "--tank", "T2: these 6 fish are already recorded", str(tmp_path / "a.json"))
    store = Store(tmp_path / "ledger.db")
    assert len(store.surveys("T2")) == 1
    store.close()


def test_a_survey_that_fails_records_nothing_and_a_recorded_one_names_its_out_json_whole(farm, tmp_path):
    """A page (--plot) that cannot be written failed the survey after it was recorded and OUT.json put
    in place: a retry recorded it twice. And OUT.json given relative was recorded relative: a
    controller running elsewhere could not open it."""
    from controller.store import Store
    d, _ = farm
    cfg = ("--config", _farm_toml(tmp_path)[0], "--tank", "T2")
    bad = run(*common(d, "--dir", d / "pairs", "--json", tmp_path / "o.json", "--plot", "/proc/nope/x.png", *cfg))
    one_line_exit_2(bad, "/proc/nope/x.png", "cannot write")
    assert not (tmp_path / "o.json").exists()
    store = Store(tmp_path / "ledger.db")
    assert store.surveys("T2") == []
    store.close()
    good = subprocess.run([FISHFARM, "survey", *map(str, common(d, "--dir", d / "pairs", "--json", "rel/o.json", *cfg)),
                           "--measure", DOTS], cwd=tmp_path, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert good.returncode == 0, good.stderr
    store = Store(tmp_path / "ledger.db")
    [s] = store.surveys("T2")
    store.close()
    assert s.source == str(tmp_path / "rel" / "o.json")


def test_a_wild_length_is_left_out_and_said(farm, tmp_path):
    d, _ = farm
    rig = convergent_rig()
    lengths_mm = [100.0, 104.0, 108.0, 112.0, 250.0]        # one 2.3x the median: two fish taken for one
    (tmp_path / "pairs").mkdir()
    for i, length in enumerate(lengths_mm):
        axis = np.array([1.0, 0.0, 0.0])
        fish = [(rig.target + axis * length / 2, rig.target - axis * length / 2)]
        for side, img in zip("LR", standin.draw_fish(rig, fish), strict=True):
            cv2.imwrite(str(tmp_path / "pairs" / f"p{i}_{side}.png"), img)
    r = run(*common(d, "--dir", tmp_path / "pairs", "--json", tmp_path / "out.json", "--csv", tmp_path / "fish.csv"))
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "out.json").read_text())
    assert doc["count"] == 4 and doc["rejected_lengths_cm"] == [pytest.approx(25.0, abs=0.1)]
    assert [f["outlier"] for f in sorted(doc["fish"], key=lambda f: f["length_cm"])] == [False] * 4 + [True]
    rows = [r.split(",") for r in (tmp_path / "fish.csv").read_text().splitlines()]
    assert rows[0][-1] == "outlier" and len(rows) == 6
    by_length = sorted(doc["fish"], key=lambda f: f["length_cm"])
    assert sorted((float(r[2]), r[-1]) for r in rows[1:]) == [
        (pytest.approx(f["length_cm"]), str(int(f["outlier"]))) for f in by_length]
    assert doc["length_cm"]["mean"] == pytest.approx(np.mean(lengths_mm[:4]) / 10, abs=0.05)
    assert "4 fish in 5 pairs" in r.stderr and "1 left out as measuring errors (25.0 cm)" in r.stderr


def _marked(mark: str) -> list[int]:
    """Processes whose environment carries FISHFARM_TEST_MARK=mark: a survey, its forkserver, its workers."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if f"FISHFARM_TEST_MARK={mark}".encode() in (entry / "environ").read_bytes().split(b"\0"):
                    out.append(int(entry.name))
            except OSError:             # gone meanwhile, or not ours to read
                pass
    return out


def _shared_frames(pids: list[int]) -> set[str]:
    """The survey's shared-memory frame files (/dev/shm, not multiprocessing's semaphores) that the
    processes ``pids`` have mapped, as /proc/PID/maps names them ("... (deleted)": no name left)."""
    out = set()
    for pid in pids:
        with contextlib.suppress(OSError):
            out |= {line.split(None, 5)[-1] for line in Path(f"/proc/{pid}/maps").read_text().splitlines()
                    if "/dev/shm/" in line and "/dev/shm/sem." not in line}
    return out


def _until(condition, timeout_s: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def _as_from_a_terminal() -> None:
    for sig in (signal.SIGHUP, signal.SIGINT):
        signal.signal(sig, signal.SIG_DFL)


def _no_traceback(p: subprocess.Popen) -> None:
    said = p.stderr.read().decode()
    assert "Traceback" not in said and "Exception ignored" not in said, said


def _exit_or_stacks(p: subprocess.Popen, timeout_s: float):
    """The process's exit status, or a failure carrying its threads' stacks (py-spy) if it is still
    running after ``timeout_s``: a hang seen once in a loaded full run is then seen where it hangs."""
    try:
        return p.wait(timeout_s)
    except subprocess.TimeoutExpired:
        spy = Path(sys.executable).parent / "py-spy"
        dump = subprocess.run([str(spy), "dump", "--native", "--pid", str(p.pid)], capture_output=True,
                              text=True, timeout=60) if spy.exists() else None
        pytest.fail(f"still running {timeout_s} s after the signal:\n"
                    f"{dump.stdout + dump.stderr if dump else '(no py-spy to show where)'}")


@pytest.fixture
def hanging_survey(farm, tmp_path):
    """`fishfarm survey` of an RG video (frames decoded here, handed over in shared memory) whose 2
    workers hang in every pair; yields (process, out.json path, mark) once the workers hold frames."""
    yield from _hanging_survey(farm, tmp_path)


@pytest.fixture
def hanging_survey_group(farm, tmp_path):
    """``hanging_survey`` in a session of its own, as a command started at a terminal is."""
    yield from _hanging_survey(farm, tmp_path, start_new_session=True)


def _hanging_survey(farm, tmp_path, start_new_session: bool = False):
    d, _ = farm
    make_mp4(tmp_path / "rg.mp4", cv2.imread(str(d / "rg0.png")), 20)
    mark = f"{os.getpid()}-{time.monotonic_ns()}"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "FISHFARM_TEST_HANG": "1", "FISHFARM_TEST_MARK": mark}
    out = tmp_path / "o.json"
    out.write_text("a survey's OUT.json of last week")
    out.with_suffix(".csv").write_text("its FISH.csv")
    p = subprocess.Popen([FISHFARM, "survey", *map(str, common(d, "--rg-video", tmp_path / "rg.mp4", "--json", out,
                                                               "--csv", out.with_suffix(".csv"), "--workers", "2")),
                          "--measure", "tests.controller.surveys.standin:measure_or_hang"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                         # as from a terminal, whatever this run's: nohup ignores SIGHUP for its children,
                         # and a shell's background job (`make test &`) SIGINT, and an ignored signal
                         # stays ignored through exec (Python then installs no KeyboardInterrupt for it)
                         preexec_fn=_as_from_a_terminal, start_new_session=start_new_session)
    try:
        assert _until(lambda: _shared_frames([q for q in _marked(mark) if q != p.pid])), "no worker took a frame"
        yield p, out, mark
    finally:
        for pid in _marked(mark):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        p.wait(10)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_ends_a_survey_at_once_its_workers_with_it_and_leaves_the_old_outputs(hanging_survey, sig):
    p, out, mark = hanging_survey
    p.send_signal(sig)
    assert _exit_or_stacks(p, 10) == 128 + sig      # not waiting an hour for the pairs in flight
    _no_traceback(p)
    assert _until(lambda: not _marked(mark)), "a worker outlived its survey"
    # last week's files as they were (the CSV was truncated to its header here), no part-file left
    assert out.read_text() == "a survey's OUT.json of last week"
    assert out.with_suffix(".csv").read_text() == "its FISH.csv"
    assert sorted(f.name for f in out.parent.iterdir()) == ["o.csv", "o.json", "rg.mp4"]


def test_a_second_ctrl_c_ends_a_survey_at_once_without_a_traceback(hanging_survey):
    """The second Ctrl-C came during the first one's clean-up (or the interpreter's end) as a
    KeyboardInterrupt: 'Exception ignored in: <module threading>' and a traceback (5 of 5 tries of a
    tester's under load)."""
    p, out, mark = hanging_survey
    p.send_signal(signal.SIGINT)
    p.send_signal(signal.SIGINT)
    assert _exit_or_stacks(p, 10) in (130, -signal.SIGINT)     # its clean-up done, or cut short by the second
    _no_traceback(p)
    assert _until(lambda: not _marked(mark)), "a worker outlived its survey"
    assert out.read_text() == "a survey's OUT.json of last week"


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGHUP])
def test_a_survey_killed_outright_is_outlived_by_no_worker_nor_its_shared_frames(hanging_survey, sig):
    """SIGKILL; and SIGHUP (a terminal closed), which killed it by its default action until the
    command took it as SIGTERM (129)."""
    p, _, mark = hanging_survey
    frames = _shared_frames(_marked(mark))
    assert frames and all(f.endswith("(deleted)") for f in frames), frames     # nothing named to leave behind
    p.send_signal(sig)
    assert p.wait(10) == (-sig if sig == signal.SIGKILL else 128 + sig)
    assert _until(lambda: not _marked(mark)), "a worker outlived its survey"


def test_a_hangup_of_the_whole_process_group_ends_a_survey_without_a_traceback(hanging_survey_group):
    """A closed terminal signals its whole process group: multiprocessing's resource tracker, which
    ignores SIGINT and SIGTERM only, died of it, and the survey's clean-up printed "resource_tracker:
    process died unexpectedly, relaunching" and a KeyError traceback a semaphore."""
    p, out, mark = hanging_survey_group
    os.killpg(p.pid, signal.SIGHUP)
    assert _exit_or_stacks(p, 10) == 128 + signal.SIGHUP
    _no_traceback(p)
    assert _until(lambda: not _marked(mark)), "a worker outlived its survey"
    assert out.read_text() == "a survey's OUT.json of last week"


@pytest.mark.parametrize("per, entries, seen, most, said", [
    ("fish", 6, 6, 1, ""),
    ("track", 3, 3, 3, " (3 measurements of 3 tracked fish, those seen in at least 3 pairs counted)"),
    ("track", 40, 7, 1, " (40 measurements of 7 tracked fish)"),
])
def test_a_video_survey_line_says_why_its_count_is_not_its_measurements(per, entries, seen, most, said):
    """'0 fish in 3 pairs' while the JSON listed 3 measured fish: in video a fish counts once, and
    at 5 frames a second or more only once seen in 3 pairs."""
    from controller.cli.survey_cmd import _tracked
    summary = {"statistics_per": per, "fish_entries": entries, "tracks": {"seen": seen, "min_sightings": most}}
    assert _tracked(summary) == said


@pytest.mark.parametrize("every, warned", [(1, False), (5, False), (6, True), (25, True)])
def test_a_video_surveyed_sparsely_is_warned_of_its_tracks(farm, tmp_path, every, warned):
    """At 1 pair a second the tracker joined two fish and counted one twice, without a word."""
    d, _ = farm
    make_mp4(tmp_path / "rg.mp4", cv2.imread(str(d / "rg0.png")), 26)
    r = run(*common(d, "--rg-video", tmp_path / "rg.mp4", "--every", every, "--json", tmp_path / "o.json"))
    assert r.returncode == 0, r.stderr
    lines = [line for line in r.stderr.splitlines() if line.startswith("fishfarm survey: warning: pairs")]
    if warned:
        assert lines == [f"fishfarm survey: warning: pairs {every / 25:.2f} s apart (--every {every} at 25 "
                         "frames/s): a fish may swim out of its track's reach between pairs and be counted twice, "
                         "or two fish be joined; --every 5 or less surveys 5 pairs a second or more"], r.stderr
    else:
        assert lines == [], r.stderr


def test_a_floor_for_the_underwater_setup_exits_2_naming_it(farm):
    """The floor's distance is the surface setup's (cameras over a tank): given for underwater
    cameras it would be silently ignored."""
    d, _ = farm
    r = run(*common(d, "--dir", d / "pairs", "--json", d / "x.json", "--floor-mm", "1000"))
    one_line_exit_2(r, "--floor-mm", "surface setup")


@pytest.mark.parametrize("summary, none", [
    ({"frames": 3, "count": 0, "fish_entries": 0}, True),
    ({"frames": 3, "count": 0}, True),                        # stills: no entries field to count
    ({"frames": 3, "count": 0, "fish_entries": 5}, False),    # measured; no track long enough to count
    ({"frames": 0, "count": 0, "fish_entries": 0}, False),
    ({"frames": 3, "count": 2, "fish_entries": 7}, False)])
def test_no_fish_in_any_pair_is_said_only_when_none_was_measured(summary, none):
    from controller.cli.survey_cmd import measured_none
    assert measured_none(summary) is none


def test_a_still_of_more_megapixels_than_any_camera_is_refused_from_its_header(farm, tmp_path):
    """A 0.9 MB PNG declaring 30000x30000, under the 2^30 pixels OpenCV reads, with a calibration
    that gives no image size: decoded, it took 5.1 GB (an outside tester)."""
    d, _ = farm
    calib = json.loads((d / "calib.json").read_text())
    (tmp_path / "p_only.json").write_text(json.dumps({"P1": calib["P1"], "P2": calib["P2"]}))
    for side in "LR":
        (tmp_path / f"big_{side}.png").write_bytes(huge_png(30000, 30000))
    r = run("--calib", tmp_path / "p_only.json", "--species", "sparus_aurata", "--setup", "underwater",
            "--pair", tmp_path / "big_L.png", tmp_path / "big_R.png", "--json", tmp_path / "x.json")
    one_line_exit_2(r, "big_L.png: 30000x30000 pixels: more than any survey camera's 50 megapixels")
