"""One weight survey end to end: a frame source in, OUT.json (and FISH.csv) out. The library entry
of ``fishfarm survey`` (the benchmark calls it too).

Weights are W = a L^b with the species' (or the stock's) coefficients. The statistics use one
entry per fish in independent stills, and one per track in video: a fish lingering in front of
the cameras for 50 frames counts once, at the robust mean of its sightings' lengths
(vision.tracking.FishTracker). The ``fish`` list stays per frame, each entry with its ``track``.
A length the survey's others make implausible (vision.survey_stats.implausible: a stereo match gone
wrong) is left out of the statistics, as the controller's survey stop does: OUT.json lists it in
``rejected_lengths_cm`` and marks its entries ``outlier``.
"""
from __future__ import annotations

import contextlib
import importlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from controller.surveys.frames import Source
from controller.surveys.outputs import SurveyFiles, fish_entry
from controller.surveys.runner import MEASURE, Measure, PairResult, measure_all
from controller.surveys.species import SurveySpecies
from vision.calib_file import StereoCalibration
from vision.survey_stats import implausible, summarise
from vision.survey_types import SurveySetup


@dataclass
class SurveyOptions:
    setup: SurveySetup
    species: SurveySpecies
    workers: int | None = None
    seed: int = 1
    measure: str | Measure = MEASURE
    read_in: str = "worker"
    on_pair: Callable[[PairResult], None] | None = None       # progress, warnings
    extra: dict = field(default_factory=dict)                  # more optional OUT.json fields
    # (lengths, weights, scores) the statistics use, once OUT.json is in place: a survey that fails
    # records nothing, so a retry does not record it twice
    record: Callable[[np.ndarray, np.ndarray, np.ndarray], None] | None = None
    # the summary, before the files are put in place: a page of it (--plot) that cannot be written
    # fails the survey with nothing replaced and nothing recorded
    before_commit: Callable[[dict], None] | None = None
    remote: dict | None = None          # measure_remote's keywords (session, site, ...): vision workers


# A fish in view for 0.6 s or more is seen this often at 5 surveyed frames a second; below that
# rate a real fish may be seen once or twice, and every track counts.
CONFIRMING_RATE = 5.0


def _import_quietly(module: str) -> None:
    """Import ``module`` ahead of its use; a failure is left for that use to report."""
    with contextlib.suppress(Exception):
        importlib.import_module(module)


class _Tracks:
    """Track ids: in video a fish is followed across frames (vision.tracking); in stills each fish
    is its own.

    In video a track of fewer than CONFIRMED sightings is most likely a false detection (a real
    fish lingers): the statistics leave such tracks out when frames are surveyed at
    CONFIRMING_RATE a second or more."""

    def __init__(self, fps: float | None, every: int = 1):
        self.fps, self.every = fps, every
        self._tracker = None
        self.lengths: list[float] = []
        self.scores: list[float] = []
        self.min_sightings = 1
        self.tracks_seen = 0
        if fps is not None:
            # the tracker's imports (filterpy, scipy: ~0.4 s of CPU) on a thread, while the workers
            # start and measure the first pairs, instead of before the survey can start them
            # (a daemon: a survey stopped by a signal meanwhile does not wait for the import to end)
            threading.Thread(target=_import_quietly, args=("vision.tracking",), name="survey-import",
                             daemon=True).start()

    @property
    def per(self) -> str:
        return "track" if self.fps is not None else "fish"

    @property
    def tracker(self):
        if self._tracker is None and self.fps is not None:
            from vision.tracking import CONFIRMED, FishTracker  # imported here: stills never need it
            self._tracker = FishTracker(self.fps)
            self.min_sightings = CONFIRMED if self.fps / max(self.every, 1) >= CONFIRMING_RATE else 1
        return self._tracker

    def update(self, frame: int, fish: list) -> list[int]:
        if self.tracker is not None:
            return [int(i) for i in self.tracker.update(frame, fish)]
        first = len(self.lengths)
        self.lengths.extend(f.length_cm for f in fish)
        self.scores.extend(f.score for f in fish)
        return list(range(first, first + len(fish)))

    def lengths_cm(self, pairs: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ids, lengths, scores) of the entries the statistics may use: every fish in stills, the
        confirmed tracks in video (a track's score: its sightings' mean); lengths that are not a
        positive number left out. A clip of fewer pairs than CONFIRMED confirms a track seen in all
        of them (else no fish of a 2-pair clip could count: every one was left out, the count 0)."""
        if self.tracker is not None:
            self.min_sightings = min(self.min_sightings, max(pairs, 1))
            tracks = self.tracker.finish()
            self.tracks_seen = len(tracks)
            kept = [t for t in tracks if t.count >= self.min_sightings]
            ids = np.array([int(t.id) for t in kept], dtype=int)
            lengths = np.array([t.length_cm for t in kept], dtype=float)
            scores = np.array([t.score for t in kept], dtype=float)
        else:
            self.tracks_seen = len(self.lengths)
            ids, lengths = np.arange(len(self.lengths)), np.asarray(self.lengths, dtype=float)
            scores = np.asarray(self.scores, dtype=float)
        usable = np.isfinite(lengths) & (lengths > 0)
        return ids[usable], lengths[usable], scores[usable]


def _results(source: Source, calib: StereoCalibration, opts: SurveyOptions):
    if opts.remote is not None:
        from controller.surveys.remote import measure_remote
        return measure_remote(source.jobs, calib, opts.setup, measure=opts.measure, local_workers=opts.workers,
                              **opts.remote)
    return measure_all(source.jobs, calib, opts.setup, measure=opts.measure, workers=opts.workers,
                       read_in=opts.read_in)


def run_survey(source: Source, calib: StereoCalibration, opts: SurveyOptions,
               json_path: str, csv_path: str | None = None) -> dict:
    """Measure every pair of ``source``, write OUT.json (and FISH.csv); return the summary
    (OUT.json without its ``fish`` list)."""
    files = SurveyFiles(json_path, csv_path)
    weight = opts.species.weight
    tracks = _Tracks(source.fps, source.every)
    stage_s: dict[str, float] = {}
    frames = 0
    started = time.perf_counter()
    results = _results(source, calib, opts)
    try:
        for result in results:
            frames += 1
            for stage, s in result.timings.items():
                stage_s[stage] = stage_s.get(stage, 0.0) + s
            ids = tracks.update(result.frame, result.fish)
            for fish, track in zip(result.fish, ids, strict=True):
                files.add(fish_entry(result.frame, track, fish, float(weight.weight_g(fish.length_cm))))
            if opts.on_pair:
                opts.on_pair(result)
        wall = time.perf_counter() - started
        ids, lengths, scores = tracks.lengths_cm(frames)
        far = implausible(lengths)
        rejected, lengths = lengths[far], lengths[~far]
        stats = summarise(lengths, weight.weight_g(lengths), rng=np.random.default_rng(opts.seed))
        head = {"species": opts.species.key, "setup": opts.setup.setup, "frames": frames}
        tail = {"count": stats["count"], "length_cm": stats["length_cm"], "weight_g": stats["weight_g"],
                "condition_k": stats["condition_k"], "precision": stats["precision"],
                "statistics_per": tracks.per, "fish_entries": files.entries,
                "tracks": {"seen": tracks.tracks_seen, "min_sightings": tracks.min_sightings},
                "species_name": opts.species.name, "coefficients": opts.species.coefficients(),
                "seed": opts.seed, "rejected_lengths_cm": [round(float(x), 2) for x in rejected],
                "stage_ms": {k: round(1e3 * v / frames, 3) for k, v in sorted(stage_s.items())} if frames else {},
                "wall_s": round(wall, 3), "pairs_per_s": round(frames / wall, 2) if wall > 0 and frames else None,
                **opts.extra}
        if opts.before_commit is not None:
            opts.before_commit({**head, **tail})
        # an entry is an outlier when the statistics left it out: an implausible length, and in
        # video a track seen too few times to be confirmed (or with no usable length)
        files.finish(head, tail, counted_tracks={int(i) for i in ids[~far]})
        if opts.record is not None:
            opts.record(lengths, weight.weight_g(lengths), scores[~far])
    finally:
        results.close()                 # a survey ended early stops its workers now, not when collected
        files.close()
    return {**head, **tail}
