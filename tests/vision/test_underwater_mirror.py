"""With ``Params(upright=True, kp_mirrored=True)`` a fish swimming one way in the image is found
like one swimming the other way (issue 7): a scene and its mirror image (both images flipped
left-right, the views swapped, the calibration mirrored with them) give nearly the same fish (the
test says why not all), and each stage that looks at the image answers alike (the keypoint net,
the fork and snout locators, eq. 13's score; the pyramid: tests/vision/test_pyramid.py)."""
from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
import pytest

from devices.sim.fish_scene import underwater_scene
from vision import fish_keypoints, fork_net, snout_net
from vision.calib_file import StereoCalibration
from vision.fins import SPAN_OF_FL, Fins, fin_scores
from vision.fork import pyramid
from vision.survey_types import SurveySetup
from vision.underwater import Params, measure_underwater

SETUP = SurveySetup(up_world=(0.0, 0.0, 1.0))
ALIKE = Params(upright=True, kp_mirrored=True)   # both directions alike (off by default: README)
WORLD = np.diag([-1.0, 1.0, 1.0, 1.0])          # the world mirrored through x = 0


@lru_cache(maxsize=8)
def scene(seed: int):
    return underwater_scene(np.random.default_rng(seed))


def mirrored(sc):
    """The scene's mirror image: (left, right, calibration) of the pair seen in a mirror."""
    W = sc.left.shape[1]
    flip = np.array([[-1.0, 0, W - 1], [0, 1, 0], [0, 0, 1]])     # x -> W - 1 - x
    c = sc.rig.calibration()
    # the mirror's left camera is the right one mirrored, and the world with it (a proper rig)
    return cv2.flip(sc.right, 1), cv2.flip(sc.left, 1), StereoCalibration(flip @ c.P2 @ WORLD,
                                                                         flip @ c.P1 @ WORLD)


def flip_x(xy: np.ndarray, W: int) -> np.ndarray:
    out = np.array(xy, float)
    out[..., 0] = W - 1 - out[..., 0]
    return out


def clear_fish(sc, cam: int):
    """(fork, snout) px of the fully visible fish in view ``cam``."""
    return [(t.fork_px[cam].astype(float), t.snout_px[cam].astype(float)) for t in sc.fish if t.fully_visible]


def test_the_keypoint_maps_of_a_mirror_image_are_its_maps_mirrored():
    img = scene(400000).left
    a, _ = fish_keypoints.maps(img, mirrored=True)
    b, _ = fish_keypoints.maps(cv2.flip(img, 1), mirrored=True)
    b = b[:, :, ::-1].copy()
    b[[2, 4, 6, 8]] *= -1                     # x components: the vectors and offsets
    assert np.allclose(a, b, atol=1e-4)


def _hypotheses(pairs, W: int | None):
    """Fork hypotheses 0.1 of the length ahead of each true fork (mirrored when W is given)."""
    xy, ang, span = [], [], []
    for f, s in pairs:
        if W is not None:
            f, s = flip_x(f, W), flip_x(s, W)
        d = s - f
        L = np.hypot(*d)
        xy.append(f + 0.1 * d)
        ang.append(np.arctan2(d[1], d[0]))
        span.append(SPAN_OF_FL * L)
    z = np.zeros(len(xy))
    return Fins(np.array(xy), np.array(ang), np.array(span), z, z.copy())


@pytest.mark.parametrize("seed", [400000, 400001])
def test_the_fork_and_snout_locators_and_the_fin_score_answer_a_mirrored_fish_alike(seed):
    sc = scene(seed)
    W = sc.left.shape[1]
    fish = clear_fish(sc, 0)
    assert fish
    pyr, pyr_m = pyramid(sc.left), pyramid(cv2.flip(sc.left, 1))
    h, h_m = _hypotheses(fish, None), _hypotheses(fish, W)
    a, b = fork_net.locate(pyr, h, upright=True), fork_net.locate(pyr_m, h_m, upright=True)
    assert np.allclose(flip_x(a.xy, W), b.xy, atol=0.02)
    assert np.allclose(a.confidence, b.confidence, atol=1e-3)
    assert np.allclose(fin_scores(pyr, h, upright=True), fin_scores(pyr_m, h_m, upright=True), atol=1e-3)
    forks = np.array([f for f, _ in fish])
    starts = np.array([s + 0.03 * (s - f) for f, s in fish])[:, None]
    tips, conf = snout_net.refine(pyr, forks, starts, upright=True)
    tips_m, conf_m = snout_net.refine(pyr_m, flip_x(forks, W), flip_x(starts, W), upright=True)
    assert np.allclose(flip_x(tips, W), tips_m, atol=0.02)
    assert np.allclose(conf, conf_m, atol=1e-3)


def _matched(fish, others) -> list[tuple]:
    """Each fish of ``fish`` with the fish of ``others`` (mirrored back) whose ends lie within 3 %
    of its length of its own, or None."""
    out = []
    for f in fish:
        snout, fork = WORLD[:3, :3] @ f.snout_mm, WORLD[:3, :3] @ f.fork_mm
        near = [g for g in others if max(np.linalg.norm(g.snout_mm - snout),
                                         np.linalg.norm(g.fork_mm - fork)) <= 0.03 * 10 * f.length_cm]
        out.append((f, near[0] if near else None))
    return out


def test_a_scene_and_its_mirror_give_the_same_fish():
    """Rendered pairs and their mirror images: as many fish within one, and nearly every fish of one
    found in the other (its ends mirrored within 3 % of its length) with its length within 1 %.
    Not every one: a mirror swaps the views' roles (forks are carried from the left view to the
    right along epipolar lines), and a fork placed a few px apart in one view moves an end more than
    3 % in depth. Over seeds 400000-400015 that is ~10 % of the reports each way, with the renderer
    before 2026-12-07 and after (its fills' edges then moved ~0.1 px), and with the default Params."""
    to_mirror, from_mirror = [], []
    for seed in range(400000, 400006):
        sc = scene(seed)
        fish = measure_underwater(sc.left, sc.right, sc.rig.calibration(), SETUP, params=ALIKE)
        fish_m = measure_underwater(*mirrored(sc), SETUP, params=ALIKE)
        assert abs(len(fish) - len(fish_m)) <= 1, f"seed {seed}"
        to_mirror += _matched(fish, fish_m)
        from_mirror += _matched(fish_m, fish)
    for found in (to_mirror, from_mirror):
        matched = [(f, g) for f, g in found if g is not None]
        assert len(found) >= 8 and len(matched) >= 0.8 * len(found)
        for f, g in matched:
            assert abs(g.length_cm / f.length_cm - 1) <= 0.01


@pytest.mark.parametrize("params, snouts, fins", [
    (Params(), True, True),                                           # the defaults: both upright
    (Params(upright_snouts=False, upright_fins=False), False, False),
    (Params(upright=True, upright_snouts=False, upright_fins=False), True, True),
])
def test_the_survey_crops_snouts_and_scores_fins_upright_by_default(monkeypatch, params, snouts, fins):
    """The snout locator's crops and eq. 13's window are upright by default (``Params.upright_snouts``,
    ``upright_fins``), so those two stages answer a fish and its mirror alike (the test above); the
    fork locator's are not unless ``upright``. Every call the survey makes is checked."""
    from vision import underwater
    seen = {"snout": set(), "fin": set(), "fork": set()}
    real_refine, real_fins, real_locate = snout_net.refine, fork_net.fin_scores, fork_net.locate

    def refine(pyr, fork_xy, pts, passes=2, upright=False):
        seen["snout"].add(upright)
        return real_refine(pyr, fork_xy, pts, passes, upright)

    def scores(pyr, fins, bank=None, upright=False):
        seen["fin"].add(upright)
        return real_fins(pyr, fins, bank, upright)

    def locate(pyr, fins, passes=2, again_above=0.3, upright=False):
        seen["fork"].add(upright)
        return real_locate(pyr, fins, passes, again_above, upright)

    monkeypatch.setattr(snout_net, "refine", refine)
    monkeypatch.setattr(fork_net, "fin_scores", scores)
    monkeypatch.setattr(underwater, "fin_scores", scores)
    monkeypatch.setattr(fork_net, "locate", locate)
    sc = scene(400000)
    assert measure_underwater(sc.left, sc.right, sc.rig.calibration(), SETUP, params=params)
    assert seen == {"snout": {snouts}, "fin": {fins}, "fork": {params.upright}}
