"""bench/bench_survey_speed.py's stills: every pair it writes is one the survey measures. The survey
surveys a still copied under another name once, and the bench cycles a few rendered scenes: until
2026-12-08 its 40- and 200-pair runs measured 20 pairs and timed the survey's start over them."""
from __future__ import annotations

import shutil

import numpy as np

from bench.bench_survey_speed import write_stills
from controller.surveys.frames import _distinct


def _scenes(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(0)
    return [tuple(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(2)) for _ in range(n)]


def test_every_still_the_bench_writes_is_surveyed_though_its_scenes_repeat(tmp_path):
    paths = write_stills(_scenes(3), 40, str(tmp_path))
    kept, warnings = _distinct(paths)
    assert kept == list(range(40)) and warnings == []


def test_the_survey_would_measure_plain_copies_once(tmp_path):
    """The rule the marks answer: the same scenes copied under other names are surveyed once."""
    paths = write_stills(_scenes(3), 3, str(tmp_path))
    for i in range(3, 9):
        copy = (str(tmp_path / f"c{i}_L.png"), str(tmp_path / f"c{i}_R.png"))
        for src, dst in zip(paths[i % 3], copy, strict=True):
            shutil.copy(src, dst)
        paths.append(copy)
    kept, warnings = _distinct(paths)
    assert kept == [0, 1, 2] and len(warnings) == 6
