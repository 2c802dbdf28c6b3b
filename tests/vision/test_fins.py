"""Caudal fins: the emboss template bank (eq. 13), frame sampling, and the fork's innermost point
located at full resolution on fish drawn from the contract's words (a body with a forked caudal fin)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.vision.fish_drawing import draw_fish_2d, water
from vision.bodies import body_ends, fish_masks
from vision.fins import (
    EMBOSS,
    Fins,
    bank_proposals,
    fin_scores,
    fork_mask,
    sample_frames,
    sample_frames_raw,
    template_bank,
)
from vision.fork import ANGLE_TRIES, locate_forks, pyramid
from vision.illumination import water_distance


def test_emboss_is_a_high_pass():
    assert EMBOSS.sum() == 0                       # flat regions (the illumination) give nothing


@pytest.mark.parametrize("angle", [0.0, 1.0, np.pi, -2.0])
def test_fork_mask_has_the_body_ahead_and_water_in_the_notch(angle):
    m = fork_mask(61, angle, 120.0, notch=0.1)
    c = 30
    ax = np.array([np.cos(angle), np.sin(angle)])
    at = lambda d: m[int(round(c + d * ax[1])), int(round(c + d * ax[0]))]   # noqa: E731
    assert at(20) > 0.9                            # peduncle ahead
    assert at(-8) < 0.1                            # notch behind the innermost point
    assert 0.3 < m[c + 1, c + 1] + m[c, c] < 1.7   # the innermost point is on the fin's edge


def test_bank_templates_are_zero_mean_unit_and_kept_by_their_basis():
    bank = template_bank(n_angles=8)
    assert np.allclose(bank.vectors.mean(axis=1), 0, atol=1e-5)
    assert np.allclose(np.linalg.norm(bank.vectors, axis=1), 1, atol=1e-5)
    approx = bank.coef @ bank.basis
    kept = (approx * bank.vectors).sum(axis=1)
    assert kept.min() > 0.9
    assert len(bank.basis) < len(bank.vectors)


def test_sample_frames_turns_and_marks_the_outside():
    ramp = np.tile(np.arange(100, dtype=np.float32), (80, 1))        # value = u
    out = sample_frames(ramp, np.array([[50.0, 40.0]]), np.array([[0.0, 1.0]]), np.array([-2.0, 0, 2.0]),
                        np.array([-3.0, 0, 3.0]))
    assert out.shape == (1, 3, 3)
    # axis points down (+v): the normal points to -u, so rows across go 53, 50, 47
    assert np.allclose(out[0, :, 1], [53, 50, 47])
    assert np.isnan(sample_frames(ramp, np.array([[99.0, 40.0]]), np.array([[1.0, 0.0]]), np.array([5.0]),
                                  np.array([0.0])))[0, 0, 0]
    u8 = sample_frames(ramp.astype(np.uint8), np.array([[10.0, 10.0]]), np.array([[1.0, 0.0]]), np.array([0.5]),
                       np.array([0.0]))
    assert abs(u8[0, 0, 0] - 10.5) <= 0.5


@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
def test_sample_frames_takes_more_frames_than_one_remap_holds(dtype):
    # OpenCV's remap refuses maps of 32767 rows or more: 800 frames of 49 rows are 39,200
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (120, 160)).astype(dtype)
    n = 800
    centres = np.c_[rng.uniform(0, 160, n), rng.uniform(0, 120, n)]
    ang = rng.uniform(-np.pi, np.pi, n)
    axes = np.c_[np.cos(ang), np.sin(ang)]
    t = np.linspace(-10, 10, 49)
    out = sample_frames(img, centres, axes, t, t)
    assert out.shape == (n, 49, 49)
    for k in (0, 700, n - 1):                   # frames in every batch sampled as alone
        assert np.array_equal(out[k], sample_frames(img, centres[k:k + 1], axes[k:k + 1], t, t)[0], equal_nan=True)


def scene(rng, fish, size=(960, 1280)):
    img = water(*size, rng)
    for xy, angle, length, value in fish:
        draw_fish_2d(img, xy, angle, length, value)
    return np.clip(img, 0, 255).astype(np.uint8)


FISH = [((300, 300), 0.1, 300, 40.0), ((900, 620), np.pi + 0.2, 200, 230.0), ((1050, 230), 2.9, 380, 90.0),
        ((250, 760), -0.3, 160, 200.0)]


@pytest.mark.parametrize("seed", [0, 1])
def test_forks_located_to_a_fraction_of_a_percent_of_the_length(seed):
    """Start each fish's search a few percent of its length and ~10 degrees off (what the body or
    the bank gives); every fork must come back within 1 % of the length (what a 3 % weight needs),
    both polarities."""
    rng = np.random.default_rng(seed)
    img = scene(rng, FISH)
    pyr = pyramid(img)
    lengths = np.array([f[2] for f in FISH], float)
    xy = np.array([f[0] for f in FISH], float) + rng.uniform(-0.03, 0.03, (4, 2)) * lengths[:, None]
    angle = np.array([f[1] for f in FISH]) + rng.choice([-1, 1], 4) * np.radians(10)
    span = 0.3 * np.array([f[2] for f in FISH], float)
    forks = locate_forks(pyr, Fins(xy, angle, span, np.ones(4), np.ones(4)))
    forks = locate_forks(pyr, forks.fins)
    assert forks.ok.all()
    for k, (true_xy, true_angle, length, _) in enumerate(FISH):
        assert np.linalg.norm(forks.fins.xy[k] - true_xy) < 0.01 * length
        assert abs(np.angle(np.exp(1j * (forks.fins.angle[k] - true_angle)))) < np.radians(4)


def test_no_fork_on_a_straight_edge_or_a_snout():
    rng = np.random.default_rng(3)
    img = water(400, 400, rng)
    img[:, 200:] -= 80                                             # a straight edge
    snout = draw_fish_2d(img, (60, 330), 0.0, 250, 230.0)          # a snout tip at (310, 330)
    img = np.clip(img, 0, 255).astype(np.uint8)
    cands = Fins(np.array([[200.0, 100.0], snout]), np.array([0.0, np.pi]), np.array([75.0, 75.0]),
                 np.ones(2), np.ones(2))
    assert not locate_forks(pyramid(img), cands).ok.any()


def test_bank_scores_forks_above_snouts_and_edges():
    """Eq. (13) where candidates are: the bank (emboss + fork templates at the fin's angle and
    scale) scores each drawn fork well above the same fish's snout end and a straight edge."""
    rng = np.random.default_rng(4)
    img = scene(rng, FISH)
    img[:, 1200:] = 0                                           # a straight edge
    pyr = pyramid(img)
    xy = np.array([f[0] for f in FISH], float)
    angle = np.array([f[1] for f in FISH])
    span = 0.3 * np.array([f[2] for f in FISH], float)
    forks = fin_scores(pyr, Fins(xy, angle, span, np.ones(4), np.ones(4)))
    snouts = fin_scores(pyr, Fins(xy + (np.array([f[2] for f in FISH]) * [np.cos(angle), np.sin(angle)]).T,
                                  angle + np.pi, span, np.ones(4), np.ones(4)))
    edge = fin_scores(pyr, Fins(np.array([[1200.0, 480.0]]), np.array([0.0]), np.array([80.0]), np.ones(1), np.ones(1)))
    assert forks.min() > 0.5
    assert forks.min() > snouts.max() + 0.1
    assert forks.min() > edge.max() + 0.1


def test_body_ends_give_both_ends_of_each_fish_with_its_axis():
    rng = np.random.default_rng(5)
    img = scene(rng, FISH)
    small = cv2.resize(img, (320, 240), interpolation=cv2.INTER_AREA)
    ends, length = body_ends(fish_masks(water_distance(small, 120, 130), (2.0,))[0], 4.0, 4.0, 20)
    for xy, angle, L, _ in FISH:
        k = np.linalg.norm(ends.xy - xy, axis=1).argmin()
        assert np.linalg.norm(ends.xy[k] - xy) < 0.2 * L
        assert 0.75 * L < length[k] < 1.2 * L
        assert abs(np.angle(np.exp(1j * (ends.angle[k] - angle)))) < np.radians(10)


def test_square_cut_tail_located_at_its_rear_edge():
    """A tail with no notch (tilapia, worn fins): the fork is the middle of the straight rear edge;
    found to 1.5 % of the length from a start a few percent off, while a straight edge that goes
    on past the fin (above) is still refused."""
    rng = np.random.default_rng(5)
    img = water(600, 800, rng)
    length, rear = 300.0, np.array([300.0, 300.0])                  # head towards +x
    cv2.ellipse(img, (int(rear[0] + 0.55 * length), 300), (int(0.45 * length), int(0.14 * length)), 0, 0, 360,
                40.0, -1, cv2.LINE_AA)                                # the body
    fin = np.array([[rear[0], 300 - 0.15 * length], [rear[0] + 0.12 * length, 300 - 0.03 * length],
                    [rear[0] + 0.12 * length, 300 + 0.03 * length], [rear[0], 300 + 0.15 * length]])
    cv2.fillPoly(img, [np.round(fin * 16).astype(np.int32)], 60.0, cv2.LINE_AA, shift=4)   # the fin
    img = np.clip(img, 0, 255).astype(np.uint8)
    start = rear + np.array([0.04, -0.02]) * length
    forks = locate_forks(pyramid(img), Fins(start[None], np.array([0.1]), np.array([0.3 * length]),
                                            np.ones(1), np.ones(1)))
    assert forks.ok.all()
    assert np.linalg.norm(forks.fins.xy[0] - rear) < 0.015 * length


def test_bank_proposes_forks_among_its_best_peaks():
    """Eq. (13) over a whole reduced water-distance image (the second fork proposer, beside the
    bodies' ends): at least half the drawn forks, either polarity, are among its 10 best peaks,
    within 5 % of their length and 25 degrees of their axis, in full-resolution pixels, beside a
    straight edge and water texture (a weak proposer on its own: the locator sorts them out)."""
    rng = np.random.default_rng(6)
    img = scene(rng, FISH)
    img[:, 1200:] = 0                                           # a straight edge
    small = cv2.resize(img, (320, 240), interpolation=cv2.INTER_AREA)
    props = bank_proposals(water_distance(small, 120, 130), 4.0, 4.0, 10)
    assert 0 < len(props) <= 10
    hits = 0
    for xy, angle, L, _ in FISH:
        turn = np.abs(np.angle(np.exp(1j * (props.angle - angle))))
        hits += bool(np.any((np.linalg.norm(props.xy - xy, axis=1) < 0.05 * L) & (turn < np.radians(25))))
    assert hits >= 2


def test_a_fork_started_on_an_axis_45_degrees_off_is_found_by_turning_it():
    """Along an axis 45 degrees off its fin's a drawn fork shows no V (one lobe leaves the rows);
    the turned axes (``tries``) find it within 1 % of the length, and a straight edge stays no fork."""
    pyr = pyramid(scene(np.random.default_rng(7), FISH))
    cands = Fins(np.array([f[0] for f in FISH], float), np.array([f[1] for f in FISH]) + np.radians(45),
                 0.3 * np.array([f[2] for f in FISH], float), np.ones(4), np.ones(4))
    assert not locate_forks(pyr, cands).ok.any()
    turned = locate_forks(pyr, cands, tries=ANGLE_TRIES)
    assert turned.ok.all()
    for k, (true_xy, _, length, _) in enumerate(FISH):
        assert np.linalg.norm(turned.fins.xy[k] - true_xy) < 0.01 * length
    img = water(400, 400, np.random.default_rng(3))
    img[:, 200:] -= 80                                             # a straight edge
    edge = Fins(np.array([[200.0, 100.0]]), np.array([0.0]), np.array([75.0]), np.ones(1), np.ones(1))
    assert not locate_forks(pyramid(np.clip(img, 0, 255).astype(np.uint8)), edge, tries=ANGLE_TRIES).ok.any()


@pytest.mark.parametrize("notch_deg", [60.0, 75.0])
def test_a_fork_before_a_ledge_is_traced_from_inside_the_fin(notch_deg, monkeypatch):
    """A ledge of the fish's own brightness behind the tail (reef, another fish) is met first by
    every row scanned from the back: a straight edge, no fork. Traced from inside the fin back to
    the first water, the notch is found, within 1 % of the length."""
    import vision.fork as fork_mod
    rng = np.random.default_rng(int(notch_deg))
    img = water(400, 500, rng)
    length, fork = 300.0, np.array([130.0, 200.0])
    draw_fish_2d(img, fork, 0.0, length, 200.0, notch_deg=notch_deg)
    x0 = int(fork[0] - 0.18 * length)
    img[:, x0:x0 + 6] = 200.0
    pyr = pyramid(np.clip(img, 0, 255).astype(np.uint8))
    cand = Fins(fork[None] + [[4.0, -3.0]], np.array([0.1]), np.array([0.3 * length]), np.ones(1), np.ones(1))
    found = locate_forks(pyr, cand)
    assert found.ok[0]
    assert np.linalg.norm(found.fins.xy[0] - fork) < 0.01 * length
    monkeypatch.setattr(fork_mod, "INSIDE_FROM", None)            # the scan from the back alone
    assert not locate_forks(pyr, cand).ok[0]


def test_body_ends_of_all_bodies_at_once_match_each_body_measured_alone():
    """The vectorised ends (moments by bincount, grouped quantiles) equal the per-body figures."""
    mask = np.zeros((120, 160), np.uint8)
    cv2.ellipse(mask, (50, 40), (30, 8), 20, 0, 360, 1, -1)
    cv2.ellipse(mask, (110, 85), (36, 10), -35, 0, 360, 1, -1)
    cv2.ellipse(mask, (130, 20), (5, 5), 0, 0, 360, 1, -1)             # round: no axis, no ends
    ends, length = body_ends(mask, 2.0, 2.0, 20)
    assert len(ends) == 4
    n, labels = cv2.connectedComponents(mask)
    for lab in range(1, n):
        ys, xs = np.nonzero(labels == lab)
        pts = np.c_[xs, ys].astype(float)
        c = pts.mean(axis=0)
        evals, evecs = np.linalg.eigh(np.cov((pts - c).T))
        if np.sqrt(evals[1] / evals[0]) < 1.8:
            continue
        t = (pts - c) @ evecs[:, 1]
        lo, hi = np.quantile(t, [0.002, 0.998])
        for end in (lo, hi):
            want = (c + end * evecs[:, 1] + 0.5) * 2.0 - 0.5
            assert np.linalg.norm(ends.xy - want, axis=1).min() < 1e-9
        assert np.abs(length - 2.0 * (hi - lo)).min() < 1e-9


def test_raw_frames_are_the_samples_with_a_mask_where_the_float_ones_are_nan():
    """``sample_frames_raw`` (uint8, no float copy) gives the same samples as ``sample_frames``,
    its mask exactly where those are NaN (frames inside, across the edge, wholly outside)."""
    rng = np.random.default_rng(2)
    img = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    centres = np.array([[40.0, 30.0], [2.0, 30.0], [79.5, 59.0], [-50.0, 10.0]])
    ang = np.array([0.3, 1.0, 2.0, -0.5])
    axes = np.c_[np.cos(ang), np.sin(ang)]
    t = np.linspace(-6, 6, 9)
    ref = sample_frames(img, centres, axes, t, t)
    raw, off = sample_frames_raw(img, centres, axes, t, t)
    assert raw.dtype == np.uint8 and off is not None
    assert np.array_equal(off, np.isnan(ref).any(axis=3))
    assert np.array_equal(raw.astype(np.float32)[~off], ref[~off])
    assert not off[0].any() and off[1].any() and off[3].all()
    inside, none = sample_frames_raw(img, centres[:1], axes[:1], t, t)
    assert none is None and np.array_equal(inside.astype(np.float32), ref[:1])
