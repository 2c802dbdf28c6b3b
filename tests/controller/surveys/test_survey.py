"""The survey library entry with stand-ins for the per-pair pipeline (tests/controller/surveys/standin.py)."""
import csv
import json
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import cv2
import numpy as np
import pytest

from controller.errors import BadInput
from controller.surveys.frames import Source, still_source
from controller.surveys.species import survey_species
from controller.surveys.survey import SurveyOptions, run_survey
from controller.surveys.video_frames import video_source
from devices.sim.stereo_rig import convergent_rig
from tests.controller.surveys import standin

STANDIN = "tests.controller.surveys.standin"


def options(measure, workers=1, species="sparus_aurata", **kw):
    sp = survey_species(species)
    return SurveyOptions(sp.setup("underwater", (0.0, 0.0, 1.0)), sp, workers=workers, measure=measure, **kw)


def stills(tmp_path, rig, rng, counts, colour=False):
    items, truth = [], []
    for i, n in enumerate(counts):
        fish = standin.random_fish(rig, rng, n)
        left, right = standin.draw_fish(rig, fish, colour)
        items.append((str(tmp_path / f"{i}_L.png"), str(tmp_path / f"{i}_R.png")))
        cv2.imwrite(items[-1][0], left)
        cv2.imwrite(items[-1][1], right)
        truth.append(sorted(np.linalg.norm(s - f) / 10 for s, f in fish))
    return items, truth


@pytest.mark.parametrize("workers", [1, 2])
def test_true_projected_fish_come_out_at_their_length_and_weight(tmp_path, workers):
    rig = convergent_rig()
    items, truth = stills(tmp_path, rig, np.random.default_rng(5), [3, 0, 2, 4], colour=workers == 2)
    out = tmp_path / "out.json"
    summary = run_survey(still_source(items), rig.calibration(), options(f"{STANDIN}:dots", workers),
                         str(out), str(tmp_path / "fish.csv"))
    doc = json.loads(out.read_text())
    assert doc["frames"] == 4 and doc["count"] == 9 == len(doc["fish"]) and doc["statistics_per"] == "fish"
    assert set(doc) >= {"species", "setup", "frames", "fish", "count", "length_cm", "weight_g"}
    for frame, lengths in enumerate(truth):
        got = sorted(f["length_cm"] for f in doc["fish"] if f["frame"] == frame)
        assert got == pytest.approx(lengths, rel=0.01)
    for f in doc["fish"]:
        assert f["weight_g"] == pytest.approx(0.02263 * f["length_cm"] ** 3.032, rel=1e-3)
        assert f["condition_k"] == pytest.approx(100 * f["weight_g"] / f["length_cm"] ** 3, rel=1e-3)
        assert np.linalg.norm(np.subtract(f["snout_mm"], f["fork_mm"])) / 10 == pytest.approx(f["length_cm"], abs=2e-3)
        assert f["quality"]["residual_px"] < 1
    assert len({f["track"] for f in doc["fish"]}) == 9
    assert doc["weight_g"]["mean"] == pytest.approx(np.mean([f["weight_g"] for f in doc["fish"]]), rel=1e-4)
    assert doc["coefficients"]["a"] == 0.02263 and set(doc["stage_ms"]) >= {"read", "measure", "dots"}
    assert summary["count"] == 9
    rows = (tmp_path / "fish.csv").read_text().splitlines()
    assert rows[0].startswith("frame,track,length_cm,weight_g,condition_k,score,snout_x_mm") and len(rows) == 10
    assert float(rows[1].split(",")[2]) == doc["fish"][0]["length_cm"]


def test_results_come_back_in_frame_order_from_a_pool(tmp_path):
    # frames with a low level take longest: a pool finishes them out of order
    from controller.surveys.frames import PairJob
    levels = [5, 39, 1, 20, 38, 2, 30, 3]
    # decoded frames go to the workers through shared memory; one larger than the first frame's
    # slot goes by pipe instead, and colour and grey frames mix
    sizes = [(4, 4), (4, 4), (9, 7), (4, 4), (2, 2, 3), (4, 4), (4, 4), (4, 4)]
    jobs = (PairJob(i * 2, f"p{i}", left=np.full(sz, lv, np.uint8), right=np.full(sz, lv, np.uint8))
            for i, (lv, sz) in enumerate(zip(levels, sizes, strict=True)))
    calib = convergent_rig(image_size=(2, 2)).calibration()   # principal points inside every frame
    calib.image_size = None                     # a CALIB.json with only P1, P2 fits frames of any size
    summary = run_survey(Source(jobs, None), calib, options(f"{STANDIN}:slow_by_level", workers=2),
                         str(tmp_path / "o.json"))
    doc = json.loads((tmp_path / "o.json").read_text())
    assert [f["frame"] for f in doc["fish"]] == [0, 2, 4, 6, 8, 10, 12, 14]
    assert [f["length_cm"] for f in doc["fish"]] == pytest.approx(levels)
    assert [f["quality"]["shared_memory"] for f in doc["fish"]] == [1, 1, 0, 1, 1, 1, 1, 1]
    assert summary["frames"] == 8


def test_a_detector_cannot_spoil_the_shared_frames_later_pairs_reuse(tmp_path):
    # 12 decoded pairs through 4 shared slots: each slot carries three pairs in turn. A detector
    # painting its frames must not paint what a later pair in that slot is measured on
    from controller.surveys.frames import PairJob
    levels = [11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22]
    jobs = (PairJob(i, f"p{i}", left=np.full((6, 8), lv, np.uint8), right=np.full((6, 8), lv, np.uint8))
            for i, lv in enumerate(levels))
    calib = convergent_rig(image_size=(8, 6)).calibration()
    run_survey(Source(jobs, None), calib, options(f"{STANDIN}:scribbles", workers=2), str(tmp_path / "o.json"))
    doc = json.loads((tmp_path / "o.json").read_text())
    assert [f["length_cm"] for f in doc["fish"]] == pytest.approx(levels)
    # shared frames come read-only: the detector is refused, not left to write where others read
    assert [f["quality"]["shared_memory"] for f in doc["fish"]] == [1] * 12
    assert [f["quality"]["wrote"] for f in doc["fish"]] == [0] * 12


def test_an_empty_survey_is_count_zero(tmp_path):
    rig = convergent_rig()
    items, _ = stills(tmp_path, rig, np.random.default_rng(1), [0, 0])
    second = cv2.imread(items[1][0], cv2.IMREAD_UNCHANGED)
    second[0, 0] ^= 1                  # two moments of empty water, not one still given twice
    cv2.imwrite(items[1][0], second)
    run_survey(still_source(items), rig.calibration(), options(f"{STANDIN}:no_fish"), str(tmp_path / "o.json"))
    doc = json.loads((tmp_path / "o.json").read_text())
    assert doc["count"] == 0 and doc["fish"] == [] and doc["frames"] == 2
    assert doc["weight_g"]["mean"] is None and doc["weight_g"]["histogram"] == {"edges": [], "counts": []}


def test_a_bad_image_in_a_worker_fails_the_survey_by_name_and_leaves_no_output(tmp_path):
    rig = convergent_rig()
    items, _ = stills(tmp_path, rig, np.random.default_rng(1), [1, 1, 1])
    (tmp_path / "1_R.png").write_bytes(b"garbage")
    with pytest.raises(BadInput, match=r"1_R.png: not a readable image"):
        run_survey(still_source(items), rig.calibration(), options(f"{STANDIN}:dots", workers=2),
                   str(tmp_path / "o.json"))
    assert not list(tmp_path.glob("o.json*"))


def test_a_calibration_for_other_frames_is_refused_by_name(tmp_path):
    rig = convergent_rig(image_size=(640, 480))
    items, _ = stills(tmp_path, rig, np.random.default_rng(1), [1])
    calib = convergent_rig().calibration()            # 1280x960
    with pytest.raises(BadInput, match=r"0_L.png: does not fit the calibration: image_size: "
                                         r"calibration made for 1280x960 images, the frames are 640x480"):
        run_survey(still_source(items), calib, options(f"{STANDIN}:dots"), str(tmp_path / "o.json"))


def _stand_in_tracker(monkeypatch, ids_of):
    """vision.tracking replaced: a tracker giving the fish of pair ``frame`` the ids ``ids_of(frame,
    n)``; each track's length the median of its sightings."""
    class Track:
        def __init__(self, i, lengths):
            self.id, self.length_cm, self.count, self.score = i, float(np.median(lengths)), len(lengths), 0.5

    class FishTracker:
        def __init__(self, fps):
            assert fps == pytest.approx(25.0)
            self.seen = {}

        def update(self, frame, fish):
            ids = ids_of(frame, len(fish))
            for i, f in zip(ids, fish, strict=True):
                self.seen.setdefault(i, []).append(f.length_cm)
            return ids

        def finish(self):
            return [Track(i, v) for i, v in self.seen.items()]

    monkeypatch.setitem(sys.modules, "vision.tracking", types.SimpleNamespace(FishTracker=FishTracker, CONFIRMED=3))


def _two_fish_videos(tmp_path, frames=6):
    """(the rig, its two fish, two MJPG videos of them standing still) at 25 frames/s."""
    rig = convergent_rig()
    fish = standin.random_fish(rig, np.random.default_rng(3), 2)
    left, right = standin.draw_fish(rig, fish, colour=True)
    paths = []
    for side, img in (("l", left), ("r", right)):
        out = cv2.VideoWriter(str(tmp_path / f"{side}.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, rig.image_size)
        for _ in range(frames):
            out.write(img)
        out.release()
        paths.append(str(tmp_path / f"{side}.avi"))
    return rig, fish, tuple(paths)


def test_video_statistics_use_one_entry_per_track(tmp_path, monkeypatch):
    """With vision.tracking present, a fish seen in many frames counts once, at its track's length."""
    _stand_in_tracker(monkeypatch, lambda frame, n: list(range(n)))    # the stand-in's fish keep their order
    rig, fish, paths = _two_fish_videos(tmp_path)
    summary = run_survey(video_source(paths), rig.calibration(), options(f"{STANDIN}:dots"), str(tmp_path / "o.json"))
    doc = json.loads((tmp_path / "o.json").read_text())
    assert len(doc["fish"]) == 12 and doc["count"] == 2 == summary["count"]
    assert doc["statistics_per"] == "track" and {f["track"] for f in doc["fish"]} == {0, 1}
    truth = sorted(np.linalg.norm(s - f) / 10 for s, f in fish)
    assert sorted(doc["length_cm"]["histogram"]["edges"])[0] <= truth[0]
    assert doc["length_cm"]["mean"] == pytest.approx(np.mean(truth), rel=0.02)   # MJPG blurs the dots a little


def test_entries_of_a_track_too_short_to_count_are_marked_outlier(tmp_path, monkeypatch):
    """An unconfirmed track (fewer than CONFIRMED sightings at 5 pairs/s or more) is left out of the
    statistics: its entries say so (`outlier`), in OUT.json and FISH.csv, so the count and the mean
    can be rebuilt from the fish list."""
    # the second fish is track 1 in two pairs, then track 2
    _stand_in_tracker(monkeypatch, lambda frame, n: [0, 1 if frame < 2 else 2][:n])
    rig, _, paths = _two_fish_videos(tmp_path)
    run_survey(video_source(paths), rig.calibration(), options(f"{STANDIN}:dots"), str(tmp_path / "o.json"),
               str(tmp_path / "f.csv"))
    doc = json.loads((tmp_path / "o.json").read_text())
    assert doc["count"] == 2 and doc["tracks"] == {"seen": 3, "min_sightings": 3}
    assert {(f["track"], f["outlier"]) for f in doc["fish"]} == {(0, False), (1, True), (2, False)}
    counted = [f["length_cm"] for f in doc["fish"] if not f["outlier"]]
    assert len({f["track"] for f in doc["fish"] if not f["outlier"]}) == doc["count"] and counted
    rows = list(csv.reader((tmp_path / "f.csv").read_text().splitlines()))
    assert sorted((r[1], r[-1]) for r in rows[1:]) == sorted((str(f["track"]), str(int(f["outlier"])))
                                                             for f in doc["fish"])


@pytest.mark.parametrize("frames", [1, 2, 3])
def test_a_clip_shorter_than_a_confirmed_track_counts_the_fish_seen_in_every_pair(tmp_path, monkeypatch, frames):
    """Of a clip of fewer pairs than CONFIRMED (3), a track seen in every pair is confirmed: no fish
    of a 2-pair clip could count otherwise (it counted 0, every measured fish left out). The first
    fish is one track in every pair, the second a new track in each."""
    _stand_in_tracker(monkeypatch, lambda frame, n: [0, 1 + frame][:n])
    rig, _, paths = _two_fish_videos(tmp_path, frames=frames)
    run_survey(video_source(paths), rig.calibration(), options(f"{STANDIN}:dots"), str(tmp_path / "o.json"))
    doc = json.loads((tmp_path / "o.json").read_text())
    counted = {f["track"] for f in doc["fish"] if not f["outlier"]}
    assert doc["tracks"]["min_sightings"] == min(frames, 3)
    assert counted == ({0, 1} if frames == 1 else {0}) and doc["count"] == len(counted)
    assert doc["tracks"]["seen"] == 1 + frames


def test_implausible_lengths_are_left_out_of_the_statistics_and_marked(tmp_path):
    """The controller's rule (vision.survey_stats.implausible) holds for `fishfarm survey` too: the
    statistics, the recorded lengths and the count leave them out; OUT.json lists and marks them."""
    from controller.surveys.frames import PairJob
    from vision.survey_stats import PLAUSIBLE_LONG, PLAUSIBLE_SHORT
    levels = [10, 11, 12, 13, 30, 3]                    # slow_by_level: one fish a pair, level cm long
    median = float(np.median(levels))
    wild = {lv for lv in levels if not PLAUSIBLE_SHORT * median <= lv <= PLAUSIBLE_LONG * median}
    assert wild == {30, 3}                              # one past each end of the band
    jobs = (PairJob(i, f"p{i}", left=np.full((4, 4), lv, np.uint8), right=np.full((4, 4), lv, np.uint8))
            for i, lv in enumerate(levels))
    calib = convergent_rig(image_size=(4, 4)).calibration()
    recorded = []
    summary = run_survey(Source(jobs, None), calib,
                         options(f"{STANDIN}:slow_by_level", record=lambda ls, ws, scores: recorded.append(list(ls))),
                         str(tmp_path / "o.json"))
    doc = json.loads((tmp_path / "o.json").read_text())
    kept = [lv for lv in levels if lv not in wild]
    assert doc["count"] == summary["count"] == len(kept)
    assert doc["length_cm"]["mean"] == pytest.approx(np.mean(kept), abs=0.01)
    assert sorted(doc["rejected_lengths_cm"]) == sorted(wild)
    assert {f["length_cm"]: f["outlier"] for f in doc["fish"]} == {lv: lv in wild for lv in levels}
    assert recorded == [pytest.approx(kept)]


def test_a_survey_whose_page_fails_puts_no_file_in_place_and_records_nothing(tmp_path):
    from controller.surveys.frames import PairJob
    (tmp_path / "o.json").write_text("last week's")
    recorded, pages = [], []

    def page(summary):
        pages.append(summary["count"])
        raise BadInput("x.png", None, "cannot write: disk full")
    jobs = (PairJob(i, f"p{i}", left=np.full((4, 4), lv, np.uint8), right=np.full((4, 4), lv, np.uint8))
            for i, lv in enumerate([10, 11, 12]))
    opts = options(f"{STANDIN}:slow_by_level", record=lambda *a: recorded.append(a), before_commit=page)
    with pytest.raises(BadInput, match="disk full"):
        run_survey(Source(jobs, None), convergent_rig(image_size=(4, 4)).calibration(), opts,
                   str(tmp_path / "o.json"), str(tmp_path / "f.csv"))
    assert pages == [3] and recorded == []
    assert (tmp_path / "o.json").read_text() == "last week's" and not (tmp_path / "f.csv").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.json"]


def test_two_fish_are_never_judged_by_each_other(tmp_path):
    from controller.surveys.frames import PairJob
    jobs = (PairJob(i, f"p{i}", left=np.full((4, 4), lv, np.uint8), right=np.full((4, 4), lv, np.uint8))
            for i, lv in enumerate([5, 39]))
    run_survey(Source(jobs, None), convergent_rig(image_size=(4, 4)).calibration(),
               options(f"{STANDIN}:slow_by_level"), str(tmp_path / "o.json"))
    doc = json.loads((tmp_path / "o.json").read_text())
    assert doc["count"] == 2 and doc["rejected_lengths_cm"] == [] and not any(f["outlier"] for f in doc["fish"])


def test_a_worker_started_as_its_survey_ends_dies_without_a_traceback():
    """The forkserver's preload (controller.surveys.worker_start): a worker that cannot rebuild the
    pool's semaphore (the survey, signalled, unlinked it as it exited) exits quietly; any other
    error is printed as before. Run as the forkserver's child would meet it: sys.excepthook."""
    code = textwrap.dedent("""
        import sys, multiprocessing.synchronize as s
        import controller.surveys.worker_start
        try:
            s.SemLock.__new__(s.SemLock).__setstate__((0, 1, 1, "/fishfarm-survey-gone"))
        except FileNotFoundError:
            sys.excepthook(*sys.exc_info())
        try:
            open("/fishfarm/no/such/file")
        except FileNotFoundError:
            sys.excepthook(*sys.exc_info())
    """)
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         cwd=str(Path(__file__).resolve().parents[3]))
    assert got.stderr.count("Traceback") == 1 and "synchronize.py" not in got.stderr, got.stderr
    assert "/fishfarm/no/such/file" in got.stderr
