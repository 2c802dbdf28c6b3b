"""Rendered scenes written to disk read back as the same pixels, truth and calibration."""
import json

import cv2
import numpy as np

from devices.sim.fish_io import CALIB, main, read_truth, write_scene
from devices.sim.fish_scene import underwater_rig, underwater_scene
from vision.calib_file import calibration_from_json


def test_written_pairs_truth_and_calibration_read_back(tmp_path):
    rig = underwater_rig(image_size=(320, 240), focal_px=350.0)
    scenes = [underwater_scene(np.random.default_rng(s), rig=rig, n_fish=3) for s in range(2)]
    for k, sc in enumerate(scenes):
        write_scene(sc, tmp_path, k)
    recs = read_truth(tmp_path)
    assert [r["index"] for r in recs] == [0, 1]
    for rec, sc in zip(recs, scenes, strict=True):
        assert np.array_equal(cv2.imread(str(tmp_path / rec["left"])), sc.left)
        assert np.array_equal(cv2.imread(str(tmp_path / rec["right"])), sc.right)
        assert len(rec["fish"]) == len(sc.fish)
        for got, want in zip(rec["fish"], sc.fish, strict=True):
            np.testing.assert_allclose(got["fork_px"], want.fork_px)
            np.testing.assert_allclose(got["snout_mm"], want.snout_mm)
            assert got["measurable"] == want.measurable and got["length_cm"] == want.length_cm
        assert rec["conditions"]["visibility_mm"] == sc.conditions["visibility_mm"]
    calib = calibration_from_json(json.loads((tmp_path / CALIB).read_text()))
    np.testing.assert_allclose(calib.P1, rig.P1)
    np.testing.assert_allclose(calib.P2, rig.P2)


def test_command_writes_a_set(tmp_path, capsys):
    assert main([str(tmp_path), "--count", "1", "--setup", "surface", "--seed", "3", "--image-size", "320x240"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["pairs"] == 1 and cv2.imread(str(tmp_path / "000_L.png")).shape == (240, 320, 3)
