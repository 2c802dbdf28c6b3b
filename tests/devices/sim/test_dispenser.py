"""Physics of the simulated dispenser under a ManualClock: no server, no wall time."""
from __future__ import annotations

import math
import statistics

import pytest

from controller.config import validate_section
from controller.errors import BadInput
from devices.clock import ManualClock
from devices.sim.dispenser import DispenserPhysics, Refused, SimDispenserParams
from devices.sim.truth import TruthLog

EXACT = dict(rate_noise=0.0, rate_drift=0.0)


def machine(deliveries=None, at_box=None, truth=None, **params):
    """``deliveries`` collects (grams, t_from, t_to); ``at_box(t_from, t_to)`` -> seconds at the box."""
    clock = ManualClock()
    deliver = None if deliveries is None else (lambda grams, t_from, t_to: deliveries.append((grams, t_from, t_to)))
    physics = DispenserPhysics(SimDispenserParams(**params), clock, deliver, at_box, truth)
    return clock, physics


def box_between(spell: list[float]):
    """The carriage stands at the food box over farm time [spell[0], spell[1]] (mutable)."""
    return lambda t_from, t_to: max(0.0, min(t_to, spell[1]) - max(t_from, spell[0]))


def test_run_delivers_rate_times_time_continuously_and_counts_once():
    deliveries = []
    clock, dp = machine(deliveries, rate_g_s=10.0, hopper_start_g=1000.0, **EXACT)
    t0 = clock.now()
    dp.start_run(5.0, tag=7)
    clock.advance(2.5)
    half = dp.read()
    assert half.running and half.run_tag == 7 and half.cycles == 0
    assert half.hopper_g == pytest.approx(975.0)            # half the run, half the grams
    clock.advance(2.5)
    done = dp.read()
    assert not done.running and done.run_tag == 0
    assert (done.cycles, done.last_tag) == (1, 7)
    assert done.last_grams == pytest.approx(50.0) and done.total_grams == pytest.approx(50.0)
    assert dp.physical_total_g == pytest.approx(50.0)
    assert sum(g for g, _, _ in deliveries) == pytest.approx(50.0)
    # each delivery is the food of its own stretch of time, the stretches tile the run
    assert [(a, b) for _, a, b in deliveries] == [(t0, t0 + 2.5), (t0 + 2.5, t0 + 5.0)]
    assert all(g == pytest.approx(10.0 * (b - a)) for g, a, b in deliveries)
    clock.advance(100.0)
    assert dp.read().cycles == 1 and dp.physical_total_g == pytest.approx(50.0)


def test_stop_ends_the_run_with_a_partial_delivery():
    clock, dp = machine(rate_g_s=12.0, **EXACT)
    dp.start_run(10.0, tag=1)
    clock.advance(3.0)
    dp.stop_auger()
    clock.advance(10.0)
    state = dp.read()
    assert not state.running and state.cycles == 1
    assert state.last_grams == pytest.approx(36.0, abs=0.1)
    assert dp.physical_total_g == pytest.approx(36.0)


def test_rate_noise_per_run_and_slow_drift_the_controller_must_learn():
    clock, dp = machine(rate_g_s=10.0, rate_noise=0.04, rate_drift=0.0, hopper_start_g=8000.0, seed=5)
    for tag in range(1, 201):
        dp.start_run(1.0, tag)
        clock.advance(1.0)
    factors = [r.physical_g / 10.0 for r in dp.runs]
    assert statistics.mean(factors) == pytest.approx(1.0, abs=0.01)
    assert 0.03 < statistics.stdev(factors) < 0.05

    clock, dp = machine(rate_g_s=10.0, rate_noise=0.0, rate_drift=0.02, seed=5, hopper_start_g=8000.0)
    for tag in range(1, 301):
        dp.start_run(1.0, tag)
        clock.advance(1.0)
    rates = [r.physical_g for r in dp.runs]
    steps = [math.log(b / a) for a, b in zip(rates, rates[1:], strict=False)]
    assert max(abs(s) for s in steps) < 0.1                    # slow: small steps run to run
    assert max(rates) - min(rates) > 1.0                        # but it wanders
    assert 8.0 - 1e-9 <= min(rates) and max(rates) <= 12.5 + 1e-9  # within drift_bounds


def test_load_cell_is_quantised_and_each_run_is_within_one_resolution():
    clock, dp = machine(rate_g_s=9.87, hopper_start_g=5000.04, seed=2)
    assert dp.read().hopper_g == pytest.approx(5000.0)
    for tag in range(1, 41):
        dp.start_run(0.37 + tag * 0.11, tag)
        clock.advance(10.0)
    state = dp.read()
    measured = [r.measured_g for r in dp.runs]
    assert len(measured) == 40 and all(abs(r.measured_g - r.physical_g) <= 0.1 + 1e-9 for r in dp.runs)
    assert any(r.measured_g != pytest.approx(r.physical_g, abs=1e-6) for r in dp.runs)
    assert state.total_grams == pytest.approx(sum(measured))
    assert state.hopper_g == pytest.approx(round(dp.hopper_g, 1))
    # between refills the roundings telescope: the sum is within one resolution of the truth
    assert abs(state.total_grams - dp.physical_total_g) <= 0.1 + 1e-9


def test_jam_stalls_latches_refuses_and_clears():
    truth = TruthLog(None)
    clock, dp = machine(rate_g_s=10.0, truth=truth, **EXACT)
    dp.inject_jam(at_fraction=0.4)
    dp.start_run(10.0, tag=3)
    clock.advance(10.0)
    state = dp.read()
    assert state.jammed and not state.running and (state.cycles, state.last_tag) == (1, 3)
    assert state.last_grams == pytest.approx(40.0)            # nothing after the stall
    assert dp.runs[0].t_end - dp.runs[0].t_start == pytest.approx(4.0)
    with pytest.raises(Refused) as exc:
        dp.start_run(1.0, tag=4)
    assert exc.value.reason == "jammed"
    clock.advance(60.0)
    assert dp.read().jammed                                     # latched
    dp.clear_fault()
    dp.start_run(2.0, tag=4)
    clock.advance(1.0)
    dp.inject_jam()                                             # jam the running run, now
    state = dp.read()
    assert state.jammed and state.cycles == 2 and state.last_grams == pytest.approx(10.0)
    kinds = [r["kind"] for r in truth.records]
    assert kinds.count("jam") == 2 and kinds.count("auger_run") == 2


def test_a_resent_start_of_a_jammed_run_is_a_duplicate_not_a_jam():
    clock, dp = machine(**EXACT)
    dp.inject_jam(at_fraction=0.5)
    dp.start_run(4.0, tag=5)
    clock.advance(4.0)
    assert dp.read().jammed and dp.read().fate(5) == "done"
    with pytest.raises(Refused) as exc:
        dp.start_run(4.0, tag=5)                                # the same start, resent
    assert exc.value.reason == "value"
    with pytest.raises(Refused) as exc:
        dp.start_run(4.0, tag=6)                                # a new run
    assert exc.value.reason == "jammed"
    assert len(dp.runs) == 1


def test_random_jams_follow_the_probability():
    clock, dp = machine(jam_probability=1.0, seed=9, **EXACT)
    for tag in range(1, 21):
        dp.start_run(5.0, tag)
        clock.advance(5.0)
        assert dp.read().jammed
        dp.clear_fault()
    durations = [r.t_end - r.t_start for r in dp.runs]
    assert all(0.05 * 5 <= d <= 0.95 * 5 for d in durations) and len(set(durations)) > 10
    clock, dp = machine(jam_probability=0.0, seed=9, **EXACT)
    for tag in range(1, 21):
        dp.start_run(5.0, tag)
        clock.advance(5.0)
    assert not any(r.jammed for r in dp.runs)


def test_empty_hopper_delivers_nothing_more():
    deliveries = []
    clock, dp = machine(deliveries, rate_g_s=10.0, hopper_start_g=30.0, **EXACT)
    t0 = clock.now()
    dp.start_run(5.0, tag=1)
    clock.advance(4.0)
    state = dp.read()
    assert state.running and state.hopper_g == 0.0
    clock.advance(1.0)
    state = dp.read()
    assert state.last_grams == pytest.approx(30.0) and dp.physical_total_g == pytest.approx(30.0)
    assert deliveries == [(pytest.approx(30.0), t0, pytest.approx(t0 + 3.0))]   # it ran dry at 3 s
    dp.start_run(5.0, tag=2)
    clock.advance(5.0)
    assert dp.read().last_grams == 0.0 and dp.physical_total_g == pytest.approx(30.0)


def test_refill_only_for_the_time_at_the_food_box_up_to_capacity():
    spell = [math.inf, math.inf]
    clock, dp = machine(at_box=box_between(spell), hopper_start_g=1000.0, hopper_capacity_g=3000.0,
                        refill_rate_g_s=400.0, **EXACT)
    dp.set_gate(True)
    clock.advance(10.0)
    assert dp.read().hopper_g == 1000.0 and dp.read().refilling
    assert dp.next_event_t() is None                              # away from the box: no end in sight
    spell[:] = [clock.now() + 4.0, clock.now() + 5.5]             # arrives and leaves between two looks
    clock.advance(10.0)
    assert dp.read().hopper_g == pytest.approx(1600.0)            # 1.5 s at the box, no more
    spell[:] = [clock.now() + 1.0, math.inf]
    clock.advance(2.0)
    assert dp.read().hopper_g == pytest.approx(2000.0)
    assert dp.next_event_t() == pytest.approx(clock.now() + 2.5)  # stays at the box: full then
    clock.advance(10.0)
    assert dp.read().hopper_g == pytest.approx(3000.0)
    assert dp.physical_total_g == 0.0                           # refills are not deliveries
    with pytest.raises(Refused) as exc:
        dp.start_run(1.0, tag=1)
    assert exc.value.reason == "busy"
    dp.set_gate(False)
    dp.start_run(10.0, tag=1)
    with pytest.raises(Refused) as exc:
        dp.set_gate(True)
    assert exc.value.reason == "busy"


@pytest.mark.parametrize(("run_s", "tag", "reason"), [
    (0.0, 5, "value"), (600.5, 5, "value"), (1.0, 0, "value"), (1.0, 65536, "value"),
    (1.0, 2, "value"),          # the last run's tag: a resent start must not run twice
])
def test_bad_starts_are_refused(run_s, tag, reason):
    clock, dp = machine(**EXACT)
    dp.start_run(1.0, tag=2)
    clock.advance(1.0)
    with pytest.raises(Refused) as exc:
        dp.start_run(run_s, tag)
    assert exc.value.reason == reason
    assert dp.read().cycles == 1 and not dp.read().running


def test_start_while_running_is_busy_and_fate_tells_the_story():
    clock, dp = machine(**EXACT)
    dp.start_run(10.0, tag=11)
    with pytest.raises(Refused) as exc:
        dp.start_run(10.0, tag=12)
    assert exc.value.reason == "busy"
    assert dp.read().fate(11) == "running" and dp.read().fate(12) == "not_started"
    clock.advance(10.0)
    assert dp.read().fate(11) == "done" and dp.read().fate(12) == "not_started"


def test_params_from_farm_toml_give_one_line_errors():
    params = validate_section(SimDispenserParams, {"rate_g_s": 9.5}, "farm.toml", "sim.dispenser")
    assert params.rate_g_s == 9.5
    cases = [({"rate_gs": 9}, "sim.dispenser.rate_gs: unknown key"),
             ({"hopper_start_g": 9000}, "hopper_start_g exceeds hopper_capacity_g"),
             ({"resolution_g": 0.00015}, "whole number of milligrams"),
             ({"rate_g_s": -1}, "sim.dispenser.rate_g_s")]
    for data, text in cases:
        with pytest.raises(BadInput) as exc:
            validate_section(SimDispenserParams, data, "farm.toml", "sim.dispenser")
        assert str(exc.value).startswith("farm.toml: sim.dispenser") and text in str(exc.value)
        assert "\n" not in str(exc.value)


def test_estop_stops_the_run_closes_the_gate_and_latches_until_reset():
    truth = TruthLog(None)
    clock, dp = machine(truth=truth, rate_g_s=10.0, **EXACT)
    dp.start_run(10.0, tag=1)
    clock.advance(2.0)
    dp.estop()
    state = dp.read()
    assert state.estop and not state.running and not state.refilling
    assert (state.cycles, state.last_tag) == (1, 1) and state.last_grams == pytest.approx(20.0)
    # the device itself refuses every start and every gate opening, whatever the tag or state
    for tag in (2, 3, 1):
        with pytest.raises(Refused) as exc:
            dp.start_run(1.0, tag)
        assert exc.value.reason == "estop"
    with pytest.raises(Refused) as exc:
        dp.set_gate(True)
    assert exc.value.reason == "estop"
    dp.set_gate(False)                       # closing, stopping and clearing stay allowed
    dp.stop_auger()
    dp.clear_fault()                         # CLEAR_FAULT is not a reset of the e-stop
    dp.estop()                               # a repeated e-stop changes nothing
    clock.advance(5.0)
    assert dp.read().estop and dp.read().cycles == 1 and dp.physical_total_g == pytest.approx(20.0)
    assert [r["kind"] for r in truth.records].count("estop") == 1 and len(dp.estops) == 1
    dp.estop_reset()
    assert not dp.read().estop
    dp.start_run(1.0, tag=2)
    dp.set_gate(False)
    assert dp.read().running


def test_estop_with_the_gate_open_closes_it_and_keeps_it_closed():
    clock, dp = machine(at_box=lambda a, b: b - a, hopper_start_g=100.0)
    dp.set_gate(True)
    clock.advance(1.0)
    dp.estop()
    level = dp.hopper_g
    clock.advance(10.0)
    assert not dp.read().refilling and dp.hopper_g == level
