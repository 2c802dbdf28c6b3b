"""FloatTracker on fixes made from a known motion (no images): accuracy at irregular frame times,
heading across +-pi, coasting through dropouts, "lost" after the configured time and back at once,
gating that holds out a stray fix yet cannot lock the tracker out."""
import math

import numpy as np
import pytest

from vision.float_detect import FloatFix
from vision.float_track import MAX_SPEED_M_S, FloatTracker


def motion(t):
    """A float circling at 0.4 m/s (radius 2 m), crabbing: heading 0.2 rad off its travel."""
    a = 0.2 * t
    x, y = 10 + 2 * math.cos(a), 5 + 2 * math.sin(a)
    return x, y, math.remainder(a + math.pi / 2 + 0.2, 2 * math.pi)


def fixes(times, rng, pos_sd=0.01, head_sd=0.01, conf=0.9):
    for t in times:
        x, y, h = motion(t)
        yield t, FloatFix(x + rng.normal(0, pos_sd), y + rng.normal(0, pos_sd),
                          math.remainder(h + rng.normal(0, head_sd), 2 * math.pi), conf)


def irregular(duration, rng, lo=0.02, hi=0.15, start=1000.0):
    return start + np.cumsum(rng.uniform(lo, hi, int(duration / lo)))[: int(duration / ((lo + hi) / 2))]


def heading_error(a, b):
    return abs(math.remainder(a - b, 2 * math.pi))


def test_tracks_a_crabbing_turning_float_at_irregular_frame_times():
    rng = np.random.default_rng(1)
    tr = FloatTracker()
    pos, head = [], []
    for t, fix in fixes(irregular(40, rng), rng):
        tk = tr.step(t, fix)
        assert tk.state == "tracking" and tk.t_s == t
        assert -math.pi < tk.heading_rad <= math.pi
        x, y, h = motion(t)
        pos.append(math.hypot(tk.x_m - x, tk.y_m - y))
        head.append(heading_error(tk.heading_rad, h))
    assert np.sqrt(np.mean(np.square(pos[20:]))) < 0.015
    assert math.degrees(np.sqrt(np.mean(np.square(head[20:])))) < 1.5
    assert abs(tk.speed_m_s - 0.4) < 0.05 and tk.std_m < 0.02


def test_heading_through_plus_minus_pi_is_one_smooth_motion():
    """A spin on the spot at 1 rad/s through +-pi many times: no 2 pi jumps in the estimate."""
    tr = FloatTracker()
    worst = 0.0
    for k in range(400):
        t = k / 20
        h = math.remainder(3.0 + 1.0 * t, 2 * math.pi)
        tk = tr.step(t, FloatFix(4.0, 3.0, h, 1.0))
        if k > 20:
            worst = max(worst, heading_error(tk.heading_rad, h))
    assert math.degrees(worst) < 1.0


@pytest.mark.parametrize("gap_s", [0.5, 1.5, 3.0])
def test_dropouts_up_to_3_s_coast_as_predicted_within_0_3_m(gap_s):
    rng = np.random.default_rng(2)
    tr = FloatTracker(lost_after_s=4.0)
    times = np.arange(0, 14, 0.04)
    gap = (8.0, 8.0 + gap_s)
    for t, fix in fixes(times, rng):
        hidden = gap[0] <= t < gap[1]
        tk = tr.step(t, None if hidden else fix)
        if hidden:
            x, y, _ = motion(t)
            assert tk.state == "predicted" and math.hypot(tk.x_m - x, tk.y_m - y) <= 0.3
        else:
            assert tk.state == "tracking"


@pytest.mark.parametrize("lost_after", [1.0, 4.0, 7.5])
def test_lost_after_the_configured_time_and_tracking_on_the_first_fix_back(lost_after):
    rng = np.random.default_rng(3)
    tr = FloatTracker(lost_after_s=lost_after)
    states = []
    for t, fix in fixes(np.arange(0, 30, 0.1), rng):
        hidden = 5.0 <= t < 15.0
        tk = tr.step(t, None if hidden else fix)
        states.append((t, tk.state))
        if hidden and t - 4.9 > lost_after + 1e-9:
            assert tk.state == "lost" and tk.x_m is None and tk.heading_rad is None
            assert tr.search_region() is None
        elif hidden:
            assert tk.state == "predicted"
        else:
            assert tk.state == "tracking", (t, tk)     # including the first frame back, at 15.0
    x, y, _ = motion(15.0)
    first_back = next(s for t, s in states if t >= 15.0 - 1e-9)
    assert first_back == "tracking"


def test_a_stray_fix_far_away_is_held_out():
    rng = np.random.default_rng(4)
    tr = FloatTracker()
    for t, fix in fixes(np.arange(0, 5, 0.04), rng):
        tr.step(t, fix)
    before = tr.search_region()
    tk = tr.step(5.0, FloatFix(16.0, 8.0, 0.0, 1.0))        # a distractor pair across the pond
    assert tk.state == "predicted" and math.hypot(tk.x_m - before[0], tk.y_m - before[1]) < 0.1
    x, y, h = motion(5.04)
    tk = tr.step(5.04, FloatFix(x, y, h, 1.0))
    assert tk.state == "tracking" and math.hypot(tk.x_m - x, tk.y_m - y) < 0.02


@pytest.mark.parametrize("reinit_after", [1, 3, 5])
def test_gating_cannot_lock_out_a_float_that_really_moved(reinit_after):
    """The float swerves beyond the gate (faster than the model foresaw, within what it can do:
    0.14 m aside, within MAX_SPEED_M_S and the slack; 0.42 m in 0.04 s, before 2026-12-05, was 10 m/s):
    after reinit_after agreeing fixes it is tracked there."""
    rng = np.random.default_rng(5)
    tr = FloatTracker(reinit_after=reinit_after)
    for t, fix in fixes(np.arange(0, 5, 0.04), rng):
        tr.step(t, fix)
    x0, y0, _ = motion(4.96)
    for k in range(reinit_after + 3):
        x = x0 + 0.1 + 0.01 * k                            # 0.14 m aside, in 0.04 s steps
        tk = tr.step(5.0 + 0.04 * k, FloatFix(x, y0 + 0.1, 1.0, 1.0))
        if k + 1 < reinit_after:
            assert tk.state == "predicted", k
        else:
            assert tk.state == "tracking" and abs(tk.x_m - x) < 0.02, (k, tk)


@pytest.mark.parametrize("hidden_s", [0.3, 1.5, 3.5])
def test_a_spare_float_far_off_never_takes_the_track_while_ours_is_hidden(hidden_s):
    """A second float lies still 11 m off; ours is hidden (a bird) for hidden_s: the spare agrees
    with itself but is out of ours' reach, so the track coasts on and takes ours back."""
    tr = FloatTracker(lost_after_s=4.0)
    for k in range(100):
        tr.step(k * 0.04, FloatFix(4.0 + 0.004 * k, 0.0, 0.0, 1.0))
    t = 4.0
    while t < 4.0 + hidden_s:
        tk = tr.step(t, FloatFix(15.0, 7.0, 2.0, 1.0))    # only the spare is seen
        assert tk.state == "predicted" and abs(tk.x_m - 15.0) > 5.0, (t, tk)
        t += 0.04
    tk = tr.step(t, FloatFix(4.4 + 0.1 * (t - 4.0), 0.0, 0.0, 1.0))
    assert tk.state == "tracking" and abs(tk.x_m - 4.4 - 0.1 * (t - 4.0)) < 0.05


def test_a_float_put_back_elsewhere_by_hand_is_taken_there_once_the_track_is_lost():
    rng = np.random.default_rng(5)
    tr = FloatTracker(lost_after_s=4.0)
    for t, fix in fixes(np.arange(0, 5, 0.04), rng):
        tr.step(t, fix)
    t, states = 5.0, []
    while t < 9.2:
        states.append(tr.step(t, FloatFix(30.0, 8.0, 1.0, 1.0)).state)   # beyond 2 m/s from 4.96 s
        t += 0.04
    assert "tracking" in states and set(states[:states.index("tracking")]) <= {"predicted", "lost"}
    assert states.index("tracking") * 0.04 >= 4.0 - 0.05
    assert tr.step(t, FloatFix(30.0, 8.0, 1.0, 1.0)).x_m == pytest.approx(30.0, abs=0.05)


def test_scattered_strays_do_not_restart_the_track():
    """Held-out fixes that jump about (glints paired with blue objects) never agree: no restart."""
    tr = FloatTracker(lost_after_s=10.0)
    for k in range(50):
        tr.step(k * 0.04, FloatFix(5.0, 5.0, 0.0, 1.0))
    spots = [(15.0, 2.0), (2.0, 9.0), (18.0, 8.0), (8.0, 1.0)]
    for k in range(8):
        tk = tr.step(2.0 + 0.04 * k, FloatFix(*spots[k % 4], 0.0, 1.0))
        assert tk.state == "predicted" and abs(tk.x_m - 5.0) < 0.1


def test_the_gate_widens_while_coasting_so_a_float_back_elsewhere_is_taken():
    tr = FloatTracker(lost_after_s=20.0)
    for k in range(50):
        tr.step(k * 0.04, FloatFix(5.0, 5.0, 0.0, 1.0))
    for k in range(60):                                    # 6 s unseen: the position is uncertain
        tk = tr.step(2.0 + 0.1 * k, None)
    assert tk.state == "predicted" and tk.std_m > 1.0
    tk = tr.step(8.1, FloatFix(8.0, 6.0, 1.0, 1.0))        # 3 m on: taken on the first fix
    assert tk.state == "tracking" and abs(tk.x_m - 8.0) < 0.05


def test_low_confidence_fixes_count_as_dropouts_and_weak_ones_pull_less():
    tr = FloatTracker(min_confidence=0.3)
    tr.step(0.0, FloatFix(1.0, 1.0, 0.0, 1.0))
    assert tr.step(0.04, FloatFix(1.0, 1.0, 0.0, 0.1)).state == "predicted"
    strong, weak = FloatTracker(), FloatTracker()
    for tr_, conf in ((strong, 1.0), (weak, 0.35)):
        for k in range(25):
            tr_.step(k * 0.04, FloatFix(1.0, 1.0, 0.0, 1.0))
        tr_.step(1.0, FloatFix(1.03, 1.0, 0.0, conf))
    assert strong.search_region()[0] - 1.0 > weak.search_region()[0] - 1.0 > 0


def test_search_region_holds_the_float_and_grows_while_unseen():
    rng = np.random.default_rng(6)
    tr = FloatTracker()
    assert tr.search_region() is None and tr.step(0.0, None).state == "lost"
    for t, fix in fixes(np.arange(0, 4, 0.04), rng):
        tr.step(t, fix)
    x, y, r = tr.search_region()
    assert math.hypot(x - motion(3.96)[0], y - motion(3.96)[1]) < 0.05 and r >= 0.5
    for k in range(20):
        tr.step(4.0 + 0.04 * k, None)
    assert tr.search_region()[2] > r


def test_frames_at_the_same_time_and_bad_settings():
    tr = FloatTracker()
    tr.step(1.0, FloatFix(1.0, 1.0, 0.0, 1.0))
    assert tr.step(1.0, FloatFix(1.0, 1.0, 0.0, 1.0)).state == "tracking"    # a repeated frame
    with pytest.raises(ValueError, match="lost_after_s"):
        FloatTracker(lost_after_s=0)
    with pytest.raises(ValueError, match="reinit_after"):
        FloatTracker(reinit_after=0)


def test_search_region_looks_ahead_to_the_frame_time():
    tr = FloatTracker()
    for k in range(40):                                   # 1 m/s along +x, frames 0.2 s apart
        tr.step(k * 0.2, FloatFix(0.2 * k, 3.0, 0.0, 1.0))
    x_next, _, r_next = tr.search_region()
    x_later, y, r_later = tr.search_region(7.8 + 0.6)
    assert abs(x_next - 8.0) < 0.03 and abs(x_later - 8.4) < 0.05 and abs(y - 3.0) < 0.02
    assert r_later > r_next


def test_position_only_fixes_keep_the_position_while_the_heading_coasts_and_never_start_a_track():
    """The orange disc alone (the blue one over a blue tarp): position and speed follow it, the
    heading coasts on and grows uncertain; past max_heading_std_rad the pose is only "predicted",
    and such fixes never start a track from "lost"."""
    rng = np.random.default_rng(5)
    tr = FloatTracker(max_heading_std_rad=0.12)
    t, wrong = 0.0, 2.5                                        # the heading a position-only fix carries: a guess
    for _ in range(100):                                       # 4 s of full fixes, straight at 0.25 m/s
        t += 0.04
        tr.step(t, FloatFix(2.0 + 0.25 * t + rng.normal(0, 0.01), 3.0 + rng.normal(0, 0.01), 0.0, 0.9))
    states = []
    for _ in range(75):                                        # 3 s of position-only fixes
        t += 0.04
        tk = tr.step(t, FloatFix(2.0 + 0.25 * t + rng.normal(0, 0.01), 3.0 + rng.normal(0, 0.01), wrong, 0.5,
                                 heading_known=False))
        states.append(tk.state)
        assert abs(tk.x_m - (2.0 + 0.25 * t)) < 0.05 and abs(tk.y_m - 3.0) < 0.05, tk
        assert heading_error(tk.heading_rad, 0.0) < 0.3, tk        # coasting, not pulled to the guess
    assert states[0] == "tracking" and states[-1] == "predicted", states
    assert tr.heading_std() > 0.12
    while tr.state != "lost":                                  # then it goes, and position-only fixes
        t += 0.04                                              # do not bring it back
        tr.step(t, None)
    for _ in range(10):
        t += 0.04
        assert tr.step(t, FloatFix(5.0, 3.0, wrong, 0.9, heading_known=False)).state == "lost"
    assert tr.step(t + 0.04, FloatFix(5.0, 3.0, 0.1, 0.9)).state == "tracking"


@pytest.mark.parametrize("spare_m, hidden_s", [(0.6, 0.3), (0.75, 0.5), (1.0, 0.3), (1.0, 1.0), (1.5, 1.5),
                                               (2.0, 2.0), (3.0, 3.0)])
def test_a_second_float_near_ours_seen_while_ours_is_hidden_never_takes_the_track(spare_m, hidden_s):
    """Another cleaner's float spare_m to the north, at our pace (0.2 m/s east), comes into view as
    ours is hidden (hidden_s): farther from where ours was last seen than the cleaner can go in that
    time (MAX_SPEED_M_S, plus the slack), so the track coasts and takes ours back when it shows again
    (both in view then: the detector's search region gives the one the track expects)."""
    assert spare_m > MAX_SPEED_M_S * (hidden_s + 0.1) + 0.25 + 0.06
    tr = FloatTracker()
    step, t = 0.1, 0.0
    while t < 2.0 - 1e-9:
        tk = tr.step(t, FloatFix(6 + 0.2 * t, 5.0, 0.0, 1.0))
        t += step
    assert tk.state == "tracking"
    while t < 2.0 + hidden_s - 1e-9:
        tk = tr.step(t, FloatFix(6 + 0.2 * t, 5.0 + spare_m, 1.5, 1.0))      # the spare alone
        assert tk.state in ("predicted", "lost") and (tk.y_m is None or abs(tk.y_m - 5.0) < 0.1), (t, tk)
        t += step
    tk = tr.step(t, FloatFix(6 + 0.2 * t, 5.0, 0.0, 1.0))
    assert tk.state == "tracking" and abs(tk.y_m - 5.0) < 0.05 and abs(tk.heading_rad) < 0.05


def test_a_spare_seen_beside_ours_never_takes_the_track_while_ours_is_hidden():
    """An outside tester: ours at 0.3 m/s east, a spare lying still 1 m off at right angles; ours hidden
    for 2.5 s. The spare, in reach of ours by then and turned 90 degrees, was taken as a spin and
    followed for good. Seen beside ours, it is a spare: the track coasts and takes ours back."""
    tr = FloatTracker()
    spare = FloatFix(9.0, 4.8, math.pi / 2, 1.0)
    t = 5.0
    while t < 8.0 - 1e-9:                                # both in view; the scans list the spare
        scan = tr.wants_scan(t)
        tk = tr.step(t, FloatFix(6 + 0.3 * (t - 5.0), 4.0, 0.0, 1.0,
                                 others=((spare.x_m, spare.y_m),) if scan else ()))
        assert tk.state == "tracking"
        t += 0.1
    while t < 10.5 - 1e-9:                               # ours hidden: the spare alone is seen
        tk = tr.step(t, spare)
        assert tk.state == "predicted" and abs(tk.y_m - 4.0) < 0.05 and abs(tk.heading_rad) < 0.05, (t, tk)
        t += 0.1
    for _ in range(20):
        tk = tr.step(t, FloatFix(6 + 0.3 * (t - 5.0), 4.0, 0.0, 1.0))
        assert tk.state == "tracking" and abs(tk.x_m - (6 + 0.3 * (t - 5.0))) < 0.05
        t += 0.1


def test_a_heading_jump_away_from_the_prediction_is_no_spin():
    """A fix in the gate whose heading jumped 90 degrees is a spin only where ours is predicted: 0.6 m
    aside it is held out (a run of such fixes still restarts the track: gating cannot lock out)."""
    def tracked():
        tr = FloatTracker()
        for k in range(30):
            tr.step(0.1 * k, FloatFix(5.0 + 0.03 * k, 5.0, 0.0, 1.0))
        for k in range(8):                               # hidden 0.8 s: the gate has widened
            tr.step(3.0 + 0.1 * k, None)
        return tr
    x = 5.0 + 0.03 * 38
    tk = tracked().step(3.8, FloatFix(x, 5.0, math.pi / 2, 1.0))
    assert tk.state == "tracking" and abs(tk.heading_rad - math.pi / 2) < 0.05      # spun in place
    tr = tracked()
    tk = tr.step(3.8, FloatFix(x, 5.6, math.pi / 2, 1.0))
    assert tk.state == "predicted" and abs(tk.y_m - 5.0) < 0.05 and abs(tk.heading_rad) < 0.05
    states = [tr.step(3.8 + 0.1 * k, FloatFix(x, 5.6, math.pi / 2, 1.0)).state for k in range(1, 6)]
    assert "tracking" in states


def test_scans_are_asked_for_now_and_then_while_tracking_only():
    tr = FloatTracker(scan_every_s=2.0)
    assert not tr.wants_scan(0.0)                        # nothing tracked: the whole frame is searched
    tr.step(0.0, FloatFix(5.0, 5.0, 0.0, 1.0))
    asked = []
    for t in np.arange(0.1, 6.01, 0.1):
        if tr.wants_scan(t):
            asked.append(t)
        tr.step(t, FloatFix(5.0, 5.0, 0.0, 1.0))
    assert len(asked) == 3 and np.allclose(np.diff(asked), 2.0, atol=0.11), asked
    tr.step(6.1, None)
    assert not tr.wants_scan(8.5)                        # predicted: no whole-frame pass on top


def test_a_spare_never_starts_the_track_and_a_spare_ours_stands_on_is_forgotten():
    tr = FloatTracker(lost_after_s=1.0)
    tr.step(0.0, FloatFix(5.0, 5.0, 0.0, 1.0, others=((8.0, 5.0),)))
    for k in range(1, 30):                               # lost; the spare alone in view
        tk = tr.step(0.1 * k, FloatFix(8.0, 5.0, 1.0, 1.0))
    assert tk.state == "lost"
    assert tr.step(3.0, FloatFix(2.0, 2.0, 0.0, 1.0)).state == "tracking"       # ours, elsewhere
    tr2 = FloatTracker()
    tr2.step(0.0, FloatFix(5.0, 5.0, 0.0, 1.0, others=((5.3, 5.0),)))
    tr2.step(1.0, FloatFix(5.3, 5.0, 0.0, 1.0))          # ours where the spare was: the spare is gone
    for k in range(1, 50):
        tr2.step(1.0 + 0.1 * k, None)
    assert tr2.state == "lost" and tr2.step(6.0, FloatFix(5.3, 5.0, 0.0, 1.0)).state == "tracking"


def test_drawn_frames_a_spare_beside_ours_while_ours_is_hidden_through_track_frame():
    """The tester's clip redrawn from the marker contract (tests/vision/float_drawing.py), through
    the call the cleaner makes per frame: no pose given as tracked is ever 0.3 m off ours."""
    from tests.vision import float_drawing as fd
    from vision.float_track import track_frame
    view = fd.view()
    tr = FloatTracker()
    states = []
    for k in range(131):
        t = 1000.0 + 0.1 * k
        ours = (6.0 + 0.3 * (t - 1000.0), 4.0, 0.0)
        img = fd.water(view, k % 5)
        if t - 1000.0 >= 5.0:                              # the spare put there once ours is tracked
            fd.float_marker(img, view, 9.0, 4.8, math.pi / 2)
        hidden = 8.0 <= t - 1000.0 < 10.5
        if not hidden:
            fd.float_marker(img, view, *ours)
        tk, _ = track_frame(tr, t, img, view.H)
        states.append(tk.state)
        if tk.state == "tracking":
            assert math.hypot(tk.x_m - ours[0], tk.y_m - ours[1]) < 0.3 and abs(tk.heading_rad) < 0.1, (t, tk)
        assert tk.state != "tracking" or not hidden, (t, tk)
    assert states[-20:] == ["tracking"] * 20 and "predicted" in states
