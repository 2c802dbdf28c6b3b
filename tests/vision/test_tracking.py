"""Tracking fish across video frames in 3-D: each fish counted once, its length the robust mean.

The swims are drawn here from the issue's words, independently of the tracker: fish of 15-45 cm
swimming at 0.5-1.5 body lengths a second, turning, pitching a little, kept inside a volume in
front of the cameras; a detector that sees each end with a few mm of noise, misses some fish and
reports some false fish. The tracker is scored as a survey would use it: tracks of at least
MIN_COUNT sightings are fish; a fish with two such tracks is counted twice.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vision.survey_types import FishMeasurement
from vision.tracking import FishTracker, Track, robust_length_cm

FPS = 25.0
MIN_COUNT = 3                                  # what a survey keeps as a fish
BOX_LO = np.array([-1000.0, 800.0, -1200.0])    # mm: 2 m wide, 1 m deep, 0.8 m high in front of the rig
BOX_HI = np.array([1000.0, 1800.0, -400.0])


@dataclass
class Path:
    """A true fish: midpoints (n, 3) and unit snout-ward directions (n, 3) at every video frame."""

    length_mm: float
    mid: np.ndarray
    direction: np.ndarray


@dataclass
class Swim:
    fish: list[Path]
    frames: list[int] = field(default_factory=list)                 # frame numbers given to the tracker
    seen: list[list[FishMeasurement]] = field(default_factory=list)
    truth: list[list[int]] = field(default_factory=list)            # true fish index per sighting, -1 false


def _direction(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    return np.c_[np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)]


def straight(length_mm: float, start, yaw_deg: float, speed_bl_s: float, n: int) -> Path:
    """A fish swimming straight and level at a constant speed."""
    yaw = np.full(n, np.radians(yaw_deg))
    d = _direction(yaw, np.zeros(n))
    t = np.arange(n)[:, None] / FPS
    return Path(length_mm, np.asarray(start, float) + d * speed_bl_s * length_mm * t, d)


def wander(rng: np.random.Generator, length_mm: float, n: int, start=None, yaw=None,
           turn_deg_s: float = 40.0) -> Path:
    """A fish that turns at random (rate an Ornstein-Uhlenbeck process, ~turn_deg_s), pitches up to
    ~10 degrees, changes speed within 0.5-1.5 body lengths/s, and turns back from the box's walls."""
    dt = 1.0 / FPS
    pos = rng.uniform(BOX_LO + 200, BOX_HI - 200) if start is None else np.asarray(start, float)
    yaw = rng.uniform(-np.pi, np.pi) if yaw is None else yaw
    rate, speed = 0.0, rng.uniform(0.5, 1.5)
    phase = rng.uniform(0, 2 * np.pi)
    mids, dirs = np.empty((n, 3)), np.empty((n, 3))
    for k in range(n):
        pitch = np.radians(10.0) * np.sin(phase + 0.7 * k * dt)
        rate += -rate * dt / 1.0 + np.radians(turn_deg_s) * np.sqrt(2 * dt) * rng.normal()
        outside = (pos < BOX_LO + 150) | (pos > BOX_HI - 150)
        if outside[:2].any():                              # steer to the centre at up to 90 deg/s
            want = np.arctan2(*((BOX_LO + BOX_HI)[1::-1] / 2 - pos[1::-1]))
            err = (want - yaw + np.pi) % (2 * np.pi) - np.pi
            rate = np.clip(err * 2.0, -np.pi / 2, np.pi / 2)
        yaw += rate * dt
        speed = np.clip(speed + 0.3 * np.sqrt(dt) * rng.normal(), 0.5, 1.5)
        d = _direction(np.array([yaw]), np.array([pitch]))[0]
        if outside[2]:
            d[2] = 0.3 * np.sign((BOX_LO + BOX_HI)[2] / 2 - pos[2])
            d /= np.linalg.norm(d)
        pos = pos + d * speed * length_mm * dt
        mids[k], dirs[k] = pos, d
    return Path(length_mm, mids, dirs)


def observe(rng: np.random.Generator, fish: list[Path], *, noise_mm: float = 3.0, p_seen: float = 0.9,
            false_per_frame: float = 0.0, every: int = 1, hidden: dict[int, range] | None = None,
            drop_frames: float = 0.0) -> Swim:
    """What a detector reports: each end with ``noise_mm`` of noise per axis, each fish seen with
    probability ``p_seen`` (never in its ``hidden`` frames), Poisson false fish anywhere in the box
    with random lengths and directions; every ``every``-th frame, a fraction of frames dropped."""
    swim = Swim(fish)
    n = len(fish[0].mid)
    for frame in range(0, n, every):
        if frame and rng.random() < drop_frames:
            continue
        seen, truth = [], []
        for i, f in enumerate(fish):
            if rng.random() > p_seen or (hidden and frame in hidden.get(i, ())):
                continue
            half = f.direction[frame] * f.length_mm / 2
            snout = f.mid[frame] + half + rng.normal(0, noise_mm, 3)
            fork = f.mid[frame] - half + rng.normal(0, noise_mm, 3)
            seen.append(FishMeasurement(snout, fork, np.zeros((2, 2)), np.zeros((2, 2)), rng.uniform(0.5, 1.0)))
            truth.append(i)
        for _ in range(rng.poisson(false_per_frame)):
            mid = rng.uniform(BOX_LO, BOX_HI)
            half = _direction(rng.uniform(-np.pi, np.pi, 1), rng.uniform(-0.3, 0.3, 1))[0] * rng.uniform(75, 225)
            seen.append(FishMeasurement(mid + half, mid - half, np.zeros((2, 2)), np.zeros((2, 2)),
                                        rng.uniform(0.2, 0.7)))
            truth.append(-1)
        order = rng.permutation(len(seen))
        swim.frames.append(frame)
        swim.seen.append([seen[j] for j in order])
        swim.truth.append([truth[j] for j in order])
    return swim


@dataclass
class Score:
    fish: int                 # true fish seen at least MIN_COUNT times
    counted: Counter          # true fish -> tracks (>= MIN_COUNT sightings) it is the majority of
    false_tracks: int         # tracks (>= MIN_COUNT) mostly of false detections
    impure: int               # tracks (>= MIN_COUNT) with < 90 % of their sightings from one fish
    length_error: list[float]  # relative error of each fish track's length_cm
    owner: dict[int, int] = field(default_factory=dict)   # track (>= MIN_COUNT) -> its majority fish

    @property
    def counted_twice(self) -> int:
        return sum(n - 1 for n in self.counted.values() if n > 1)

    @property
    def missed(self) -> int:
        return self.fish - len(self.counted)


def run(swim: Swim, **kw) -> tuple[list[Track], Score]:
    tracker = FishTracker(FPS, **kw)
    sightings: dict[int, list[int]] = {}
    for frame, seen, truth in zip(swim.frames, swim.seen, swim.truth, strict=True):
        ids = tracker.update(frame, seen)
        assert len(ids) == len(seen) and len(set(ids)) == len(ids)       # one track per fish per frame
        for tid, who in zip(ids, truth, strict=True):
            sightings.setdefault(tid, []).append(who)
    tracks = tracker.finish()
    assert sorted(t.id for t in tracks) == sorted(sightings)
    seen_count = Counter(who for truth in swim.truth for who in truth if who >= 0)
    counted, false_tracks, impure, errors, owner = Counter(), 0, 0, [], {}
    for t in tracks:
        assert t.count == len(sightings[t.id])
        if t.count < MIN_COUNT:
            continue
        who, n = Counter(sightings[t.id]).most_common(1)[0]
        impure += n < 0.9 * t.count
        if who < 0:
            false_tracks += 1
            continue
        counted[who] += 1
        owner[t.id] = who
        errors.append(t.length_cm * 10 / swim.fish[who].length_mm - 1)
    fish = sum(1 for n in seen_count.values() if n >= MIN_COUNT)
    return tracks, Score(fish, counted, false_tracks, impure, errors, owner)


def school(rng: np.random.Generator, n_fish: int, seconds: float) -> list[Path]:
    n = int(seconds * FPS)
    return [wander(rng, rng.uniform(150, 450), n) for _ in range(n_fish)]


# -- one fish, the API ---------------------------------------------------------------------------

def test_one_fish_swimming_is_one_track_with_its_length():
    swim = observe(np.random.default_rng(1), [wander(np.random.default_rng(2), 320.0, 250)], p_seen=1.0)
    tracks, score = run(swim)
    assert len(tracks) == 1 and score.counted == Counter({0: 1})
    assert (tracks[0].first_frame, tracks[0].last_frame, tracks[0].count) == (swim.frames[0], swim.frames[-1],
                                                                           len(swim.frames))
    assert abs(score.length_error[0]) < 0.005
    assert 0.5 <= tracks[0].score <= 1.0


def test_frames_must_increase_and_empty_frames_are_fine():
    tracker = FishTracker(FPS)
    assert tracker.update(0, []) == []
    f = FishMeasurement(np.array([0.0, 1000, -500]), np.array([-300.0, 1000, -500]),
                        np.zeros((2, 2)), np.zeros((2, 2)), 0.9)
    assert tracker.update(3, [f]) == [0]
    for frame in (3, 2):
        with pytest.raises(ValueError, match="must increase"):
            tracker.update(frame, [f])
    assert tracker.update(4, []) == []
    tracks = tracker.finish()
    assert [(t.id, t.count, t.first_frame, t.last_frame, t.length_cm) for t in tracks] == [
        (0, 1, 3, 3, pytest.approx(30.0))]
    assert tracker.finish() == [] and tracker.update(0, []) == []       # empty again: a new video


def test_a_fish_with_non_finite_ends_gets_no_track():
    nan = FishMeasurement(np.array([np.nan, 0, 0]), np.zeros(3), np.zeros((2, 2)), np.zeros((2, 2)), 0.5)
    ok = FishMeasurement(np.array([300.0, 1000, -500]), np.array([0.0, 1000, -500]),
                         np.zeros((2, 2)), np.zeros((2, 2)), 0.5)
    point = FishMeasurement(np.zeros(3), np.zeros(3), np.zeros((2, 2)), np.zeros((2, 2)), 0.5)
    assert FishTracker(FPS).update(0, [nan, ok, point]) == [-1, 0, -1]


@pytest.mark.parametrize("kw", [{"fps": 0}, {"fps": 25, "max_missed": -1}])
def test_bad_settings_are_refused(kw):
    fps = kw.pop("fps")
    with pytest.raises(ValueError):
        FishTracker(fps, **kw)


# -- the robust mean -----------------------------------------------------------------------------

def test_robust_length_ignores_wild_lengths_that_spoil_the_mean():
    rng = np.random.default_rng(5)
    lengths = np.r_[rng.normal(30.0, 0.3, 24), [42.0, 41.0, 44.0], [18.0, 20.0]]   # misplaced ends
    assert abs(np.mean(lengths) / 30.0 - 1) > 0.01
    assert robust_length_cm(lengths) == pytest.approx(30.0, rel=0.01)
    assert robust_length_cm(lengths, rng.uniform(0.3, 1.0, len(lengths))) == pytest.approx(30.0, rel=0.01)


def test_robust_length_of_few_sightings_and_weights():
    assert robust_length_cm([31.0]) == 31.0
    assert robust_length_cm([30.0, 32.0]) == pytest.approx(31.0)
    assert robust_length_cm([30.0, 32.0], [1.0, 3.0]) == pytest.approx(32.0)   # 3/4 of the weight
    assert robust_length_cm([30.0, 32.0, 33.0], trim=0.0) == pytest.approx(95.0 / 3)
    assert np.isnan(robust_length_cm([]))
    with pytest.raises(ValueError):
        robust_length_cm([30.0], trim=0.5)


# -- two fish meeting ----------------------------------------------------------------------------

@pytest.mark.parametrize("angle_deg", [25, 45, 90, 180])
@pytest.mark.parametrize("lengths", [(300.0, 310.0), (300.0, 340.0)])
def test_two_fish_crossing_keep_one_track_each(angle_deg, lengths):
    """Their midpoints meet at the same point at 2 s (10 mm apart in height), at 1 body length/s."""
    n, meet = 100, 50
    fish = []
    for length, yaw, dz in ((lengths[0], 0.0, 0.0), (lengths[1], angle_deg, 10.0)):
        d = _direction(np.radians([yaw]), np.zeros(1))[0]
        start = np.array([0.0, 1300.0, -800.0 + dz]) - d * length * meet / FPS
        fish.append(straight(length, start, yaw, 1.0, n))
    for seed in range(5):
        tracks, score = run(observe(np.random.default_rng(seed), fish, noise_mm=4.0))
        assert score.counted == Counter({0: 1, 1: 1}), (seed, [(t.id, t.first_frame, t.last_frame) for t in tracks])
        assert score.impure == 0 and score.false_tracks == 0
        assert max(map(abs, score.length_error)) < 0.01


def test_two_fish_side_by_side_with_similar_lengths_are_two_tracks():
    """Two fish 2 % apart in length swim side by side, 60 mm apart, turning together."""
    rng = np.random.default_rng(11)
    a = wander(rng, 300.0, 300, start=[0.0, 1300.0, -800.0], yaw=0.3)
    side = np.cross(a.direction, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    b = Path(306.0, a.mid + 60.0 * side, a.direction.copy())
    for seed in range(5):
        tracks, score = run(observe(np.random.default_rng(seed), [a, b], noise_mm=4.0, p_seen=0.85))
        assert score.counted == Counter({0: 1, 1: 1}) and score.impure == 0, seed
        assert max(map(abs, score.length_error)) < 0.01


# -- misses, gaps, false detections --------------------------------------------------------------

@pytest.mark.parametrize("hidden_frames", [5, 10, 15])
def test_a_fish_hidden_for_several_frames_keeps_its_track(hidden_frames):
    """Hidden (occluded, or the detector missed it) while it turns: within max_missed (15)."""
    for seed in range(5):
        rng = np.random.default_rng(100 + seed)
        fish = [wander(rng, rng.uniform(200, 400), 200, turn_deg_s=60.0)]
        swim = observe(rng, fish, p_seen=1.0, hidden={0: range(80, 80 + hidden_frames)})
        tracks, score = run(swim)
        assert len(tracks) == 1 and score.counted == Counter({0: 1}), seed


def test_a_fish_gone_longer_than_max_missed_becomes_a_new_track():
    """Beyond max_missed the tracker does not guess: the fish returns as a new track."""
    fish = [straight(300.0, [-500.0, 1300.0, -800.0], 0.0, 1.0, 100)]
    swim = observe(np.random.default_rng(3), fish, p_seen=1.0, hidden={0: range(40, 60)})
    tracks, _ = run(swim, max_missed=10)
    assert [(t.first_frame, t.last_frame) for t in tracks] == [(0, 39), (60, 99)]
    tracks, score = run(swim, max_missed=25)
    assert len(tracks) == 1 and score.counted == Counter({0: 1})


def _school_scores(every: int, drop_frames: float, seeds: range) -> list[Score]:
    scores = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        swim = observe(rng, school(rng, 20, 12.0), noise_mm=4.0, p_seen=0.85, false_per_frame=0.5,
                       every=every, drop_frames=drop_frames)
        scores.append(run(swim)[1])
    return scores


@pytest.mark.parametrize("every,drop", [(1, 0.0), (3, 0.1), (5, 0.0)])
def test_a_school_with_noise_misses_and_false_fish_is_counted_once(every, drop):
    """20 fish of 15-45 cm for 12 s, 4 mm of noise per end, 15 % missed, a false fish every other
    frame; every frame, every 3rd with 10 % dropped, every 5th. Over 3 videos (60 fish): at most
    5 % counted twice, none missed, no false fish counted, lengths within 1 % for 95 % of the fish."""
    scores = _school_scores(every, drop, range(3))
    fish = sum(s.fish for s in scores)
    assert fish == 60
    twice = sum(s.counted_twice for s in scores)
    assert twice <= 0.05 * fish, [dict(s.counted) for s in scores]
    assert sum(s.missed for s in scores) == 0
    assert sum(s.false_tracks for s in scores) == 0
    assert sum(s.impure for s in scores) <= 0.05 * fish
    errors = np.abs(np.concatenate([s.length_error for s in scores]))
    assert np.quantile(errors, 0.95) < 0.01, np.sort(errors)[-5:]


def test_false_detections_make_short_tracks_a_survey_can_drop():
    """Only false fish: none lasts MIN_COUNT sightings, and their mean score is what they scored."""
    rng = np.random.default_rng(8)
    fish = [straight(300.0, [0.0, 1300.0, -800.0], 0.0, 1.0, 250)]
    swim = observe(rng, fish, p_seen=0.0, false_per_frame=2.0)
    tracks, score = run(swim)
    assert len(tracks) > 300 and score.false_tracks == 0
    assert all(0.2 <= t.score <= 0.7 for t in tracks)


# -- on the renderer's swims ---------------------------------------------------------------------

def _rendered_swim(setup: str, seed: int, seconds: float, n_fish: int):
    """The renderer's fish swimming (devices/sim: its own motion model, fish leaving and entering
    the view) seen as a detector would: true snout and fork projected through the rig with 0.7 px
    of noise, 15 % of fish missed, 5 % with one end 15 px off along the row in the right image,
    then triangulated. Returns the Swim and, per fish, the frames it was in both images."""
    from devices.sim.fish_conditions import surface_conditions, underwater_conditions
    from devices.sim.fish_placement import populate, step_swim
    from devices.sim.fish_scene import surface_rig, underwater_rig
    from vision.triangulation import triangulate_calibrated

    rng = np.random.default_rng(seed)
    rig = underwater_rig() if setup == "underwater" else surface_rig()
    draw = underwater_conditions if setup == "underwater" else surface_conditions
    cond, _ = draw(rng, rig, n_fish, {})
    fishes, bubbles = populate(rng, rig, cond)
    calib = rig.calibration()
    swim, visible, lengths = Swim([]), {}, {}
    for frame in range(int(seconds * FPS)):
        if frame:
            fishes, bubbles = step_swim(rng, rig, cond, fishes, bubbles, 1.0 / FPS)
        seen, truth = [], []
        for f in fishes:
            ends = np.array(f.snout_fork())
            if not rig.in_view(ends).all():
                continue
            visible.setdefault(f.id, []).append(frame)
            lengths.setdefault(f.id, []).append(np.linalg.norm(ends[0] - ends[1]))
            if rng.random() > 0.85:
                continue
            p1, p2 = rig.project(ends, noise_px=0.7, rng=rng)
            if rng.random() < 0.05:
                p2[rng.integers(2), 0] += rng.choice([-15.0, 15.0])
            X, _ = triangulate_calibrated(calib, p1, p2)
            seen.append(FishMeasurement(X[0], X[1], p1, p2, rng.uniform(0.5, 1.0)))
            truth.append(f.id)
        swim.frames.append(frame)
        swim.seen.append(seen)
        swim.truth.append(truth)
    ids = sorted(lengths)
    swim.fish = {i: Path(float(np.median(lengths[i])), np.zeros((0, 3)), np.zeros((0, 3))) for i in ids}
    return swim, visible


@pytest.mark.parametrize("setup,seed", [("underwater", 1), ("surface", 2)])
def test_renderer_swims_count_each_fish_in_view_once(setup, seed):
    """A fish that leaves both images for longer than max_missed (15 frames) and comes back is a
    new track: nothing tells it from a new fish of the same size. Every other second track of a
    fish is a tracking error; those stay <= 5 % of the fish, and lengths within 1.5 % (of the median
    of the fish's true 3-D snout-fork lengths) for 90 % of them, 6 % for all. (1.5 %: above the
    nursery tank 0.7 px of pixel noise is ~3 mm of depth on an 11 cm fish, and a fish seen a few
    frames keeps part of it.)"""
    swim, visible = _rendered_swim(setup, seed, 16.0, 12)
    tracks, score = run(swim)
    assert score.fish >= 15 and score.false_tracks == 0 and score.missed <= 0.05 * score.fish
    by_fish: dict[int, list[Track]] = {}
    for t in tracks:
        if t.id in score.owner:
            by_fish.setdefault(score.owner[t.id], []).append(t)
    splits = 0
    for who, ts in by_fish.items():
        ts.sort(key=lambda t: t.first_frame)
        for a, b in zip(ts, ts[1:], strict=False):
            frames = [f for f in visible[who] if a.last_frame <= f <= b.first_frame]
            splits += len(frames) < 2 or int(np.diff(frames).max()) <= 15
    assert splits <= 0.05 * score.fish, (splits, score.fish, score.counted_twice)
    errors = np.abs(score.length_error)         # a short track may keep a misplaced end's length
    assert np.quantile(errors, 0.9) < 0.015 and errors.max() < 0.06


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.floats(50.0, 900.0), st.sampled_from([200.0, 200.5, 201.0])), min_size=1, max_size=80))
def test_a_track_s_reference_length_is_the_median_of_its_sightings_after_each(lengths):
    """The length gate's reference: np.median of every sighting so far, bit for bit (kept in order
    as they come, so a fish in view for an hour costs no more a sighting than one seen for a second)."""
    from vision.tracking import _Open
    track = _Open(0, 0, np.zeros(3), np.array([1.0, 0.0, 0.0]), lengths[0], 0.5, 1.0, 1.0)
    assert track.reference_length_mm() == lengths[0]
    for i, length in enumerate(lengths[1:], start=1):
        track.add(i, np.array([1.0, 0.0, 0.0]), length, 0.5)
        assert track.reference_length_mm() == float(np.median(lengths[:i + 1]))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(50.0, 900.0), min_size=1, max_size=80))
def test_a_long_track_keeps_a_bounded_sample_and_its_median(lengths):
    """Beyond MAX_SIGHTINGS (16 here) a track keeps that many sightings, each later one replacing a
    random one; the reference stays np.median of what is kept, bit for bit, and the count is exact."""
    import vision.tracking as tracking
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tracking, "MAX_SIGHTINGS", 16)
        track = tracking._Open(7, 0, np.zeros(3), np.array([1.0, 0.0, 0.0]), lengths[0], 0.5, 1.0, 1.0)
        for i, length in enumerate(lengths[1:], start=1):
            track.add(i, np.array([1.0, 0.0, 0.0]), length, 0.5)
            kept = list(track.lengths_mm)
            assert len(kept) == min(i + 1, 16) and track.count == i + 1
            assert list(track.sorted_mm) == sorted(kept)
            assert track.reference_length_mm() == float(np.median(kept))
            assert Counter(kept) <= Counter(lengths[:i + 1])      # each kept length was seen


def test_a_fish_in_view_for_long_is_sampled_over_the_whole_stay():
    """A fish seen 20,000 times whose reading drifts 300 -> 330 mm (the sample is uniform over the
    stay, not its first sightings: those would give ~302 mm) keeps MAX_SIGHTINGS of them; its track's
    count, frames and score (the mean of every sighting's) are exact."""
    from vision.tracking import MAX_SIGHTINGS, _Open
    n = 20_000
    lengths = np.linspace(300.0, 330.0, n)
    scores = np.where(np.arange(n) % 2 == 0, 0.2, 0.8)
    track = _Open(3, 100, np.zeros(3), np.array([1.0, 0.0, 0.0]), lengths[0], scores[0], 1.0, 1.0)
    for i in range(1, n):
        track.add(100 + i, np.array([1.0, 0.0, 0.0]), lengths[i], scores[i])
    assert len(track.lengths_mm) == len(track.scores) == len(track.sorted_mm) == MAX_SIGHTINGS
    assert abs(track.reference_length_mm() - 315.0) < 0.6          # the sample median's sd: ~0.2 mm
    done = track.close()
    assert (done.count, done.first_frame, done.last_frame) == (n, 100, 100 + n - 1)
    assert done.score == pytest.approx(0.5)
    assert abs(done.length_cm - 31.5) < 0.06
