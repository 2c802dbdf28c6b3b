"""The same fish seen in many frames of a video, counted once: tracks in 3-D.

Each track follows the midpoint of its fish's snout-fork axis with a constant-velocity Kalman filter
(filterpy; state x, vx, y, vy, z, vz in mm and mm/s; continuous white-noise acceleration scaled by
the fish's length, so a prediction's uncertainty depends on the time elapsed, not on how it is cut
into frames). Time comes from frame numbers and ``fps``, so frames may be skipped (``--every N``,
dropped frames) and the filter predicts across the gap.

A frame's fish are paired with the open tracks by one global assignment
(scipy's ``linear_sum_assignment``) on a cost that sums three chi-square-like terms, each also a gate:

- position: the Mahalanobis distance squared of the fish's midpoint from the track's prediction,
  under the prediction's covariance plus the measurement noise; gated at the 99.9 % point of
  chi-square with 3 degrees of freedom, and never farther than ``gate_mm`` (a track that has coasted
  for long has a wide covariance; the cap stops it from swallowing whatever comes near);
- length: a fish keeps its fork length, so ``(L - L_track) / (length_tol * L_track)`` squared, where
  L_track is the median of the track's sightings; gated at ``LENGTH_GATE_SIGMA``;
- heading: the snout-fork direction turns smoothly, so the angle between the fish's direction and
  the track's last one over a tolerance that grows with the time since the track was last seen
  (fish turn); gated at three tolerances. Two fish crossing head-on or at right angles cannot swap.

Tracks with CONFIRMED (3) sightings are matched first, then younger ones with the fish left over:
a track started by a false detection next to a fish cannot take that fish from its own track.
Unmatched fish start tracks. A confirmed track not seen in ``max_missed`` consecutive frames given
to ``update`` is closed (counted in updates, not video frames, so ``--every N`` does not shorten its
life in sightings); a younger one after TENTATIVE_MISSED. A fish that leaves the view for longer
comes back as a new track: re-joining by length and place was tried and joined different fish of
one stock more often than it re-joined one fish. A track's ``length_cm`` is the score-weighted interquartile mean of its
sightings' lengths (``robust_length_cm``): measurement errors are small noise plus a few wild lengths
from a misplaced snout or fork, and a bending fish reads short; the middle half's mean ignores up
to a quarter of wild values on either side while keeping most of the mean's efficiency for the
noise (a median would throw more of it away).

A track of one or two sightings may be a false detection: ``Track.count`` and ``Track.score`` (the
mean of its sightings' scores) are what a survey filters on (``count >= CONFIRMED`` is what the
tests count as a fish).

Memory stays flat over a long video: a closed track keeps its summary only (count, first and last
frame, length, score), and an open one at most ``MAX_SIGHTINGS`` sightings' lengths and scores. A
fish that stays in view longer (resting before the camera, a net knot read as a fish) keeps a
uniform random sample of them (reservoir sampling, seeded by the track's id: the same video gives
the same survey); its count stays exact and its length is the sample's, which at 4,096 sightings
differs from all of them by sampling alone (~2 % of the spread of one fish's sightings). An hour's
clip of 4 fish in view (bench_survey_speed --long-only --long-frames 90000, 2026-12-04): the survey's
tree RSS 305 -> 328 MB from 10 % to 100 % of it before, 315 -> 324 MB since; fish coming and going
kept every closed track's sightings as Python lists (~50 bytes a sighting).
"""
from __future__ import annotations

import bisect
from array import array
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import KalmanFilter
from scipy.optimize import linear_sum_assignment

POSITION_GATE = 16.27          # chi-square, 3 dof, 99.9 %
LENGTH_GATE_SIGMA = 3.5
HEADING_GATE_SIGMA = 3.0
CONFIRMED = 3                  # sightings before a track is matched first and may coast max_missed
TENTATIVE_MISSED = 2           # misses a younger track survives (most are false detections)
MAX_SIGHTINGS = 4096           # lengths and scores an open track keeps (a uniform sample beyond: module docstring)
_INADMISSIBLE = 1e9
_H = np.zeros((3, 6))
_H[0, 0] = _H[1, 2] = _H[2, 4] = 1.0


@lru_cache(maxsize=64)
def _motion(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity transition over ``dt`` s and its process noise for unit spectral density."""
    F = np.eye(6)
    F[0, 1] = F[2, 3] = F[4, 5] = dt
    return F, Q_continuous_white_noise(dim=2, dt=dt, spectral_density=1.0, block_size=3)


def robust_length_cm(lengths_cm: np.ndarray, weights: np.ndarray | None = None, trim: float = 0.25) -> float:
    """Weighted trimmed mean: the mean of the values whose cumulative weight lies in
    [trim, 1 - trim] (``trim`` 0.25: the interquartile mean), each weighted by the part of its
    weight inside that band. One value gives itself; two equal weights give their mean."""
    v = np.asarray(lengths_cm, dtype=float).reshape(-1)
    if v.size == 0:
        return float("nan")
    if not 0.0 <= trim < 0.5:
        raise ValueError(f"trim {trim}: expected 0 <= trim < 0.5")
    w = np.ones_like(v) if weights is None else np.clip(np.asarray(weights, dtype=float).reshape(-1), 1e-3, None)
    order = np.argsort(v, kind="stable")
    v, w = v[order], w[order] / w.sum()
    hi = np.cumsum(w)
    lo = hi - w
    inside = np.clip(np.minimum(hi, 1.0 - trim) - np.maximum(lo, trim), 0.0, None)
    return float((v * inside).sum() / inside.sum())


@dataclass
class Track:
    """One fish followed over frames: its summary (the sightings themselves are not kept)."""

    id: int
    count: int                          # sightings: one or two may be a false detection
    first_frame: int
    last_frame: int
    length_cm: float                    # robust mean of the sightings (robust_length_cm)
    score: float                        # mean score of the sightings


class _Open:
    """A track being built: its filter, last heading and sightings (at most MAX_SIGHTINGS of them)."""

    def __init__(self, tid: int, frame: int, mid: np.ndarray, heading: np.ndarray, length_mm: float,
                 score: float, noise_mm: float, speed_bl_s: float):
        self.id = tid
        self.kf = KalmanFilter(dim_x=6, dim_z=3)
        self.kf.x = np.array([mid[0], 0.0, mid[1], 0.0, mid[2], 0.0])
        self.kf.H = _H
        self.kf.R = np.eye(3) * noise_mm ** 2
        v_sigma = speed_bl_s * length_mm          # unknown velocity: about a body length a second
        self.kf.P = np.diag([noise_mm ** 2, v_sigma ** 2] * 3)
        self.at_frame = frame                    # frame the filter's state refers to
        self.heading = heading
        self.first_frame = self.last_frame = frame
        self.count = 1
        self.score_sum = float(score)             # every sighting's, not only the sample's
        # compact arrays (8 bytes a sighting, not a Python float's ~32)
        self.lengths_mm, self.scores = array("d", [length_mm]), array("d", [score])
        self.sorted_mm = array("d", [length_mm])     # the same lengths in order: the median without a sort
        self.ref_mm = length_mm
        self.missed = 0
        self._rng: np.random.Generator | None = None

    def reference_length_mm(self) -> float:
        """The median of the sightings' lengths kept, up to date after each ``add``."""
        return self.ref_mm

    def add(self, frame: int, heading: np.ndarray, length_mm: float, score: float) -> None:
        self.heading = heading
        self.last_frame = frame
        self.count += 1
        self.score_sum += float(score)
        self.missed = 0
        if len(self.lengths_mm) < MAX_SIGHTINGS:
            self.lengths_mm.append(length_mm)
            self.scores.append(float(score))
        else:
            # reservoir sampling (Algorithm R): every sighting so far equally likely to be kept
            if self._rng is None:
                self._rng = np.random.default_rng(self.id)
            j = int(self._rng.integers(self.count))
            if j >= MAX_SIGHTINGS:
                return
            old = self.lengths_mm[j]
            del self.sorted_mm[bisect.bisect_left(self.sorted_mm, old)]
            self.lengths_mm[j], self.scores[j] = length_mm, float(score)
        # np.median of every sighting, each time, made a fish that stays in view quadratic: an hour's
        # clip (90,000 frames) of 4 fixed fish had not been surveyed after 12 min. Kept in order instead
        # (a C memmove per sighting), the middle one or two read off, np.median's value bit for bit:
        # the hour in 4.5 min, the 3-minute clip's rate
        bisect.insort(self.sorted_mm, length_mm)
        n = len(self.sorted_mm)
        mid = self.sorted_mm[n // 2]
        self.ref_mm = float(mid if n % 2 else np.mean([self.sorted_mm[n // 2 - 1], mid]))

    def close(self) -> Track:
        lengths_cm = np.asarray(self.lengths_mm) / 10.0
        return Track(id=self.id, count=self.count, first_frame=self.first_frame, last_frame=self.last_frame,
                     length_cm=robust_length_cm(lengths_cm, np.asarray(self.scores, dtype=float)),
                     score=self.score_sum / self.count)


def _ends(fish) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Midpoint, unit snout-ward direction and length (mm) of a measurement; None if unusable."""
    snout = np.asarray(fish.snout_mm, dtype=float).reshape(3)
    fork = np.asarray(fish.fork_mm, dtype=float).reshape(3)
    axis = snout - fork
    length = float(np.linalg.norm(axis))
    if not (np.all(np.isfinite(axis)) and np.all(np.isfinite(fork))) or length <= 0.0:
        return None
    return (snout + fork) / 2.0, axis / length, length


class FishTracker:
    """Tracks of fish across the frames of one video. ``update`` each frame (frame numbers strictly
    increasing, gaps allowed), then ``finish`` for every track.

    ``gate_mm``: the farthest a fish's midpoint may lie from its track's prediction. ``max_missed``:
    frames given to ``update`` a track may go unseen before it is closed. ``noise_mm``: the
    midpoint's measurement noise (1 sigma per axis). ``speed_bl_s``: 1-sigma prior on a new track's
    speed, in body lengths/s. ``manoeuvre``: the velocity's random walk (continuous white-noise
    acceleration), body lengths/s per square-root second: a fish turning 90 degrees in a second
    at 1 body length/s changes its velocity by 1.4 body lengths/s. The continuous model keeps the
    prediction's uncertainty independent of how the time between sightings is cut into frames. ``length_tol``: 1-sigma
    relative length difference between sightings. ``turn_deg_s``: how fast the heading tolerance
    (``heading_deg`` at the next frame) widens while a track goes unseen.
    """

    def __init__(self, fps: float, *, gate_mm: float = 400.0, max_missed: int = 15, noise_mm: float = 8.0,
                 speed_bl_s: float = 1.0, manoeuvre: float = 1.0, length_tol: float = 0.07,
                 heading_deg: float = 20.0, turn_deg_s: float = 90.0):
        if not fps > 0:
            raise ValueError(f"fps {fps}: expected > 0")
        if max_missed < 0:
            raise ValueError(f"max_missed {max_missed}: expected >= 0")
        self.fps = float(fps)
        self.gate_mm = float(gate_mm)
        self.max_missed = int(max_missed)
        self.noise_mm = float(noise_mm)
        self.speed_bl_s = float(speed_bl_s)
        self.manoeuvre = float(manoeuvre)
        self.length_tol = float(length_tol)
        self.heading_deg = float(heading_deg)
        self.turn_deg_s = float(turn_deg_s)
        self._open: list[_Open] = []
        self._closed: list[Track] = []
        self._next_id = 0
        self._frame: int | None = None

    def update(self, frame: int, fish: list) -> list[int]:
        """Track id of each fish (FishMeasurement) seen in ``frame``, in order; -1 for a fish whose
        coordinates are not finite (it cannot be tracked)."""
        frame = int(frame)
        if self._frame is not None and frame <= self._frame:
            raise ValueError(f"frame {frame} after frame {self._frame}: frame numbers must increase")
        self._frame = frame
        for track in self._open:
            self._predict(track, frame)
        seen = [_ends(f) for f in fish]
        valid = [i for i, s in enumerate(seen) if s is not None]
        ids = [-1] * len(fish)
        confirmed = [t for t in self._open if t.count >= CONFIRMED]
        tentative = [t for t in self._open if t.count < CONFIRMED]
        matched = self._assign(confirmed, valid, seen, fish, frame, ids)
        matched |= self._assign(tentative, [i for i in valid if ids[i] < 0], seen, fish, frame, ids)
        for track in self._open:
            if track.id not in matched:
                track.missed += 1
        for i in valid:
            if ids[i] < 0:
                mid, heading, length = seen[i]
                track = _Open(self._next_id, frame, mid, heading, length, float(fish[i].score),
                              self.noise_mm, self.speed_bl_s)
                self._next_id += 1
                self._open.append(track)
                ids[i] = track.id
        still = []
        for track in self._open:
            limit = self.max_missed if track.count >= CONFIRMED else min(self.max_missed, TENTATIVE_MISSED)
            (self._closed.append(track.close()) if track.missed > limit else still.append(track))
        self._open = still
        return ids

    def finish(self) -> list[Track]:
        """Every track, closed, by id. The tracker is then empty and may start a new video."""
        tracks = self._closed + [t.close() for t in self._open]
        self._open, self._closed, self._frame = [], [], None
        return sorted(tracks, key=lambda t: t.id)

    # -- internals -------------------------------------------------------------------------------

    def _assign(self, tracks: list[_Open], candidates: list[int], seen: list, fish: list, frame: int,
                ids: list[int]) -> set[int]:
        """Pair ``tracks`` with the fish ``candidates`` (indices) at least total cost; the ids of
        the tracks matched. ``ids`` receives each matched fish's track id."""
        if not tracks or not candidates:
            return set()
        cost = np.vstack([self._costs(track, frame, [seen[i] for i in candidates]) for track in tracks])
        matched = set()
        for r, c in zip(*linear_sum_assignment(cost), strict=True):
            if cost[r, c] < _INADMISSIBLE:
                i = candidates[c]
                self._extend(tracks[r], frame, seen[i], fish[i].score)
                ids[i] = tracks[r].id
                matched.add(tracks[r].id)
        return matched

    def _predict(self, track: _Open, frame: int) -> None:
        dt = (frame - track.at_frame) / self.fps
        if dt <= 0:
            return
        F, Q1 = _motion(dt)
        q = (self.manoeuvre * track.reference_length_mm()) ** 2
        track.kf.predict(F=F, Q=Q1 * q)
        track.at_frame = frame

    def _costs(self, track: _Open, frame: int, seen: list) -> np.ndarray:
        """One row of the assignment cost: this track against each fish seen (inadmissible: 1e9)."""
        mids = np.array([s[0] for s in seen])
        headings = np.array([s[1] for s in seen])
        lengths = np.array([s[2] for s in seen])
        kf = track.kf
        predicted = _H @ kf.x
        S = _H @ kf.P @ _H.T + kf.R
        y = mids - predicted
        d2 = np.einsum("ni,ij,nj->n", y, np.linalg.inv(S), y)
        ref = track.reference_length_mm()
        l2 = ((lengths - ref) / (self.length_tol * ref)) ** 2
        gap_s = (frame - track.last_frame) / self.fps
        tol = np.radians(self.heading_deg + self.turn_deg_s * gap_s)
        angle = np.arccos(np.clip(headings @ track.heading, -1.0, 1.0))
        h2 = (angle / tol) ** 2
        cost = d2 + l2 + h2
        bad = ((d2 > POSITION_GATE) | (np.linalg.norm(y, axis=1) > self.gate_mm)
               | (l2 > LENGTH_GATE_SIGMA ** 2) | (h2 > HEADING_GATE_SIGMA ** 2))
        cost[bad] = _INADMISSIBLE
        return cost

    def _extend(self, track: _Open, frame: int, seen: tuple, score: float) -> None:
        mid, heading, length = seen
        track.kf.update(mid)
        track.add(frame, heading, length, score)
