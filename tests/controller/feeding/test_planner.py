import pytest

from controller.feeding.planner import Stop, next_stop, travel_s


def test_travel_time_trapezoid_and_triangle():
    assert travel_s(0, 10, 1.0, 0.5) == pytest.approx(10 + 2)      # 2 s lost to ramps
    assert travel_s(0, 0.5, 1.0, 0.5) == pytest.approx(2 * 1.0)     # never reaches cruise


def test_single_and_empty():
    s = Stop("T1", 3.0, 0.0, 5.0)
    assert next_stop([s], 0.0, 0.0) is s and next_stop([], 0.0, 0.0) is None


def test_takes_the_one_on_the_way_when_both_can_still_make_it():
    old_far = Stop("T8", 20.0, 0.0, 5.0)
    new_near = Stop("T2", 5.0, 3.0, 5.0)
    assert next_stop([old_far, new_near], 0.0, 5.0) is new_near


def test_oldest_first_when_the_detour_would_make_it_late():
    old_far = Stop("T8", 20.0, 0.0, 5.0)
    new_behind = Stop("T1", 1.0, 30.0, 5.0)
    # robot at 15 m, time 35: going back to T1 first would make T8 miss its minute
    assert next_stop([old_far, new_behind], 15.0, 35.0) is old_far


def test_never_worse_than_oldest_first():
    import random

    from controller.feeding.planner import _lateness
    rng = random.Random(5)
    better = 0
    for _ in range(300):
        stops = [Stop(f"T{i}", rng.uniform(0, 22), rng.uniform(0, 40), rng.uniform(3, 8))
                 for i in range(rng.randint(2, 6))]
        pos, now = rng.uniform(0, 22), 40.0
        by_age = sorted(stops, key=lambda s: s.raised_t)
        first = next_stop(stops, pos, now)
        planned = _lateness([first] + [s for s in by_age if s is not first], pos, now, 60.0, 1.0, 0.5)
        oldest = _lateness(by_age, pos, now, 60.0, 1.0, 0.5)
        assert max(planned, 0) <= max(oldest, 0) + 1e-9
        better += max(planned, 0) < max(oldest, 0) - 1e-9
    assert better > 10          # and it does matter on clustered demands
