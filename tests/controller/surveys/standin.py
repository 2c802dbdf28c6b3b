"""Stand-ins for vision.survey.measure_pair (same signature) while the detectors are built
elsewhere: they read fish drawn as two dots, so the survey around them is tested end to end.

``dots``: each fish is a bright dot at its snout (level >= 220) and a mid-grey dot at its fork
(100-190) in both images, drawn at the true projections of a 3-D fish. Dots are paired across
the images and along each fish in order of image row (fish drawn one above the other), then
triangulated with the real calibration: lengths come out of the real geometry.
"""
from __future__ import annotations

import time

import cv2
import numpy as np

from vision.survey_types import FishMeasurement
from vision.triangulation import triangulate_calibrated


def _centroids(grey: np.ndarray, lo: int, hi: int) -> np.ndarray:
    mask = ((grey >= lo) & (grey <= hi)).astype(np.uint8)
    n, _, stats, cent = cv2.connectedComponentsWithStats(mask)
    keep = stats[1:, cv2.CC_STAT_AREA] >= 5
    c = cent[1:][keep]
    return c[np.argsort(c[:, 1])]


def dots(left, right, calib, setup, timings=None):
    t0 = time.perf_counter()
    grey = [cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) if im.ndim == 3 else im for im in (left, right)]
    snouts = [_centroids(g, 220, 255) for g in grey]
    forks = [_centroids(g, 100, 190) for g in grey]
    n = min(len(snouts[0]), len(snouts[1]), len(forks[0]), len(forks[1]))
    fish = []
    if n:
        s3, _ = triangulate_calibrated(calib, snouts[0][:n], snouts[1][:n])
        f3, res = triangulate_calibrated(calib, forks[0][:n], forks[1][:n])
        for i in range(n):
            fish.append(FishMeasurement(s3[i], f3[i], np.array([snouts[0][i], snouts[1][i]]),
                                        np.array([forks[0][i], forks[1][i]]), score=0.9,
                                        quality={"residual_px": float(res[i])}))
    if timings is not None:
        timings["dots"] = timings.get("dots", 0.0) + time.perf_counter() - t0
    return fish


def no_fish(left, right, calib, setup, timings=None):
    return []


def scribbles(left, right, calib, setup, timings=None):
    """One fish per pair whose length (cm) is the image's top-left grey level, then an attempt to
    paint both frames white (a careless detector); ``wrote`` says whether it could."""
    level = int(left.reshape(-1)[0])
    try:
        left[...] = 255
        right[...] = 255
        wrote = 1.0
    except ValueError:                  # read-only frames
        wrote = 0.0
    z = np.zeros(3)
    return [FishMeasurement(z, np.array([10.0 * level, 0, 0]), np.zeros((2, 2)), np.zeros((2, 2)), 1.0,
                            quality={"wrote": wrote, "shared_memory": float(isinstance(left, np.memmap))})]


def slow_by_level(left, right, calib, setup, timings=None):
    """One fish per pair whose length (cm) is the image's top-left grey level; frames with a low
    level take longest, so a pool finishes them out of order."""
    level = int(left.reshape(-1)[0])
    time.sleep(0.002 * (40 - level % 40))
    z = np.zeros(3)
    return [FishMeasurement(z, np.array([10.0 * level, 0, 0]), np.zeros((2, 2)), np.zeros((2, 2)), 1.0,
                            quality={"shared_memory": float(isinstance(left, np.memmap))})]


def draw_fish(rig, fish_mm: list[tuple[np.ndarray, np.ndarray]], colour: bool = False):
    """(left, right) images of fish given as (snout, fork) world points, drawn as dots."""
    w, h = rig.image_size
    imgs = [np.full((h, w), 30, np.uint8), np.full((h, w), 30, np.uint8)]
    for snout, fork in fish_mm:
        s1, s2 = rig.project(snout)
        f1, f2 = rig.project(fork)
        for img, s, f in ((imgs[0], s1[0], f1[0]), (imgs[1], s2[0], f2[0])):
            for p, level in ((s, 250), (f, 150)):
                # 4 bits of sub-pixel: the disc's centroid is the point to ~0.05 px
                cv2.circle(img, tuple(int(round(c * 16)) for c in p), 4 * 16, level, -1, cv2.LINE_8, 4)
    if colour:
        imgs = [cv2.cvtColor(i, cv2.COLOR_GRAY2BGR) for i in imgs]
    return imgs


def random_fish(rig, rng, n: int, rows: bool = True):
    """``n`` fish around the rig's target, body near-horizontal, one above the other (rows)."""
    out = []
    for i in range(n):
        length = rng.uniform(90, 160)                       # mm
        centre = rig.target + np.array([0.0, 0.0, (i - (n - 1) / 2) * 60.0 if rows else 0.0])
        heading = rng.uniform(0, 2 * np.pi)
        axis = np.array([np.cos(heading), np.sin(heading), rng.uniform(-0.1, 0.1)])
        axis /= np.linalg.norm(axis)
        out.append((centre + axis * length / 2, centre - axis * length / 2))
    return out


def measure_or_hang(left, right, calib, setup, timings=None):
    """vision.survey.measure_pair, except in a process whose FISHFARM_TEST_HANG is set: there every
    pair hangs (a worker holding its jobs when it is killed)."""
    import os
    if os.environ.get("FISHFARM_TEST_HANG"):
        time.sleep(3600)
    from vision.survey import measure_pair
    return measure_pair(left, right, calib, setup, timings)
