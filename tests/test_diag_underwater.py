"""bench/diag_underwater.py's ``located_why``: one verdict per image in which a fish has no located
fork within 3 % of its length, none where it has one, on a rendered scene through the pipeline."""
from __future__ import annotations

import numpy as np

from bench.diag_underwater import PROPOSE_TOL, TOL, located_why
from devices.sim.fish_scene import underwater_scene
from vision.survey_types import SurveySetup
from vision.underwater import measure_underwater

VERDICTS = {"misplaced", "unsure", "both", "dropped"}


def _scene_and_trace():
    sc = underwater_scene(np.random.default_rng(13))
    tr: dict = {}
    measure_underwater(sc.left, sc.right, sc.rig.calibration(), SurveySetup(up_world=(0.0, 0.0, 1.0)), trace=tr)
    return sc, tr


def _missing(t, located) -> int:
    """Images without a located fork within TOL of the fish's length of its true fork."""
    return sum(not (np.linalg.norm(np.asarray(located[c]).reshape(-1, 2) - t.fork_px[c], axis=1)
                    <= TOL * np.linalg.norm(t.snout_px[c] - t.fork_px[c])).any() for c in (0, 1))


def test_one_verdict_per_image_missing_a_fork_and_none_elsewhere():
    sc, tr = _scene_and_trace()
    assert len(tr["hypotheses"]) == 2
    counted = 0
    for t in sc.fish:
        if not t.fully_visible:
            continue
        why = located_why(t, tr, 0.9)
        assert len(why) == _missing(t, tr["located"]) and set(why) <= VERDICTS
        counted += len(why)
    # with nothing located every visible fish gets a verdict in both images
    empty = {**tr, "located": [np.zeros((0, 2)), np.zeros((0, 2))]}
    visible = [t for t in sc.fish if t.fully_visible]
    assert visible and all(len(located_why(t, empty, 0.9)) == 2 for t in visible)
    assert sum(len(located_why(t, empty, 0.9)) for t in visible) > counted


def test_the_verdicts_split_by_place_and_by_sureness_apart():
    """Whether the locator's answer lies within 3 % does not depend on the confidence asked for:
    asked for none, every verdict is sure (``dropped`` or ``misplaced``); asked for more than any
    confidence, none is (``unsure`` or ``both``), and each image's verdict pairs with its own. (Fish
    with a hypothesis near their fork in both images: the diagnosis asks only about those.)"""
    sc, tr = _scene_and_trace()
    empty = {**tr, "located": [np.zeros((0, 2)), np.zeros((0, 2))]}
    pairs = {"dropped": "unsure", "misplaced": "both"}
    seen = set()

    def proposed(t) -> bool:
        return all((np.linalg.norm(tr["hypotheses"][c][1].xy - t.fork_px[c], axis=1)
                    <= PROPOSE_TOL * np.linalg.norm(t.snout_px[c] - t.fork_px[c])).any() for c in (0, 1))
    for t in (t for t in sc.fish if t.fully_visible and proposed(t)):
        sure, doubtful = located_why(t, empty, 0.0), located_why(t, empty, 1.01)
        assert len(sure) == len(doubtful) == 2
        assert set(sure) <= set(pairs) and [pairs[v] for v in sure] == doubtful
        seen |= set(sure)
    assert seen == set(pairs)        # the scene has forks the locator finds and forks it misses
