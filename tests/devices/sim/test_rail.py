"""Physics of the simulated rail drive, on a ManualClock: no bus, no waiting."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from devices.clock import ManualClock
from devices.rail.can_frames import Command, Fault, Op, Reason
from devices.sim.rail import SimRailMotor, SimRailParams
from devices.sim.rail_motion import plan_move, plan_stop

VMAX, ACCEL = 1.0, 0.5


def trapezoid(d: float, vmax: float, a: float, t: np.ndarray) -> np.ndarray:
    """Textbook rest-to-rest trapezoid (d >= vmax**2 / a): distance covered after t seconds."""
    ta, total = vmax / a, vmax / a + d / vmax
    return np.where(t < ta, 0.5 * a * t**2,
                    np.where(t < total - ta, 0.5 * a * ta**2 + vmax * (t - ta),
                             d - 0.5 * a * np.clip(total - t, 0, None) ** 2))


def sample(profile, times):
    return np.array([profile.at(t) for t in times])      # (n, 2): position, velocity


def test_rest_to_rest_move_is_the_textbook_trapezoid():
    t0, p0, d = 100.0, 2.0, 9.0
    prof = plan_move(t0, p0, 0.0, p0 + d, VMAX, ACCEL)
    assert prof.t_end - t0 == pytest.approx(VMAX / ACCEL + d / VMAX)
    t = np.linspace(0, prof.t_end - t0 + 1, 400)
    pv = sample(prof, t0 + t)
    np.testing.assert_allclose(pv[:, 0], p0 + trapezoid(d, VMAX, ACCEL, t), atol=1e-9)
    assert pv[:, 1].max() == pytest.approx(VMAX)
    assert np.all(np.diff(pv[:, 0]) >= -1e-12)
    assert prof.at(prof.t_end + 5) == (p0 + d, 0.0)


def test_short_move_is_a_triangle_that_never_reaches_full_speed():
    prof = plan_move(0.0, 5.0, 0.0, 4.5, VMAX, ACCEL)         # 0.5 m backwards
    peak = math.sqrt(ACCEL * 0.5)
    assert prof.t_end == pytest.approx(2 * peak / ACCEL)
    pv = sample(prof, np.linspace(0, prof.t_end, 201))
    assert pv[:, 1].min() == pytest.approx(-peak)
    assert prof.at(peak / ACCEL) == pytest.approx((4.75, -peak))
    assert prof.p_end == 4.5


def test_new_target_behind_a_moving_carriage_brakes_then_returns():
    first = plan_move(0.0, 0.0, 0.0, 10.0, VMAX, ACCEL)
    t = 5.0
    p, v = first.at(t)                                      # cruising at 1 m/s
    second = plan_move(t, p, v, 2.0, VMAX, ACCEL)
    # continuous at the command instant, in position and velocity
    assert second.at(t) == pytest.approx((p, v))
    brake = v / ACCEL
    p_turn, v_turn = second.at(t + brake)
    assert v_turn == pytest.approx(0.0, abs=1e-12)
    assert p_turn == pytest.approx(p + v * v / (2 * ACCEL))  # farthest point: the braking distance
    back = p_turn - 2.0
    assert second.t_end - (t + brake) == pytest.approx(VMAX / ACCEL + back / VMAX)
    assert second.at(second.t_end) == (2.0, 0.0)


def test_target_too_close_to_stop_for_overshoots_and_comes_back():
    p, v = 3.0, 1.0                                         # needs 1 m to stop
    prof = plan_move(0.0, p, v, 3.4, VMAX, ACCEL)
    pv = sample(prof, np.linspace(0, prof.t_end, 500))
    assert pv[:, 0].max() == pytest.approx(4.0, abs=1e-3)
    assert prof.at(prof.t_end) == (3.4, 0.0)


def test_slower_speed_limit_in_mid_travel_decelerates_to_it():
    prof = plan_move(0.0, 0.0, 1.0, 20.0, 0.4, ACCEL)
    pv = sample(prof, np.linspace(0, prof.t_end, 2000))
    assert pv[:, 1].max() == pytest.approx(1.0)
    late = pv[len(pv) // 2:, 1]
    assert late.max() == pytest.approx(0.4)
    assert prof.at(prof.t_end) == (20.0, 0.0)


def test_stop_brakes_at_the_given_rate():
    prof = plan_stop(10.0, 4.0, -0.8, 5.0)
    assert prof.t_end == pytest.approx(10.0 + 0.8 / 5.0)
    assert prof.p_end == pytest.approx(4.0 - 0.8**2 / 10.0)


# --- the motor controller ------------------------------------------------------------------

def motor(**params) -> tuple[SimRailMotor, ManualClock]:
    clock = ManualClock()
    return SimRailMotor(SimRailParams(**params), clock), clock


def cmd(op: Op, seq: int = 1, target: float = 0.0, speed: float = 0.0) -> Command:
    return Command(op, seq, target, speed)


def homed_motor(**params) -> tuple[SimRailMotor, ManualClock]:
    m, clock = motor(**params)
    assert m.handle(cmd(Op.HOME)) is Reason.ACCEPTED
    clock.advance(1000.0)
    assert m.state == "idle"
    return m, clock


def test_homing_runs_to_the_switch_at_homing_speed_and_zeroes_the_encoder():
    m, clock = motor(start_m=3.0, homing_speed_m_s=0.25)
    before = m.report()
    assert (before.state, before.homed, before.position_m) == ("unhomed", False, 0.0)  # counts from power-on
    assert m.handle(cmd(Op.MOVE, target=5.0)) is Reason.NOT_HOMED
    assert m.handle(cmd(Op.HOME, seq=7)) is Reason.ACCEPTED
    duration = 0.25 / ACCEL + 3.0 / 0.25
    clock.advance(duration / 2)
    mid = m.report()
    assert mid.state == "homing" and mid.velocity_m_s == pytest.approx(-0.25)
    assert mid.position_m == pytest.approx(m.position() - 3.0)   # encoder = true - power-on offset
    assert m.handle(cmd(Op.MOVE, seq=8, target=5.0)) is Reason.BUSY
    clock.advance(duration / 2 - 1e-3)
    assert m.state == "homing"
    clock.advance(2e-3)
    done = m.report()
    assert (done.state, done.homed, done.position_m, done.at_limit, done.seq) == ("idle", True, 0.0, True, 7)
    assert m.position() == 0.0


def test_move_arrives_at_the_trapezoid_time_and_reports_at_target():
    m, clock = homed_motor()
    t0 = clock.now()
    assert m.handle(cmd(Op.MOVE, seq=2, target=8.0)) is Reason.ACCEPTED
    total = VMAX / ACCEL + 8.0 / VMAX
    for frac in (0.1, 0.3, 0.5, 0.9):
        clock.t = t0 + frac * total
        assert m.position() == pytest.approx(float(trapezoid(8.0, VMAX, ACCEL, np.array(frac * total))))
        assert m.state == "moving" and not m.report().at_target
    clock.t = t0 + total
    st = m.report()
    assert (st.state, st.position_m, st.velocity_m_s, st.at_target, st.seq) == ("idle", 8.0, 0.0, True, 2)


def test_move_speed_in_the_command_caps_cruise_and_cannot_exceed_the_drive():
    m, clock = homed_motor()
    m.handle(cmd(Op.MOVE, target=10.0, speed=0.5))
    clock.advance(5.0)
    assert m.velocity() == pytest.approx(0.5)
    m.handle(cmd(Op.MOVE, target=20.0, speed=9.0))
    clock.advance(10.0)
    assert m.velocity() == pytest.approx(VMAX)


def test_targets_beyond_the_soft_limits_are_refused():
    m, _ = homed_motor(rail_length_m=21.0)
    assert m.handle(cmd(Op.MOVE, target=21.5)) is Reason.OUT_OF_RANGE
    assert m.handle(cmd(Op.MOVE, target=-0.1)) is Reason.OUT_OF_RANGE
    assert m.handle(cmd(Op.MOVE, target=21.0)) is Reason.ACCEPTED


def test_estop_brakes_hard_and_latches_until_cleared():
    m, clock = homed_motor(estop_decel_m_s2=4.0)
    m.handle(cmd(Op.MOVE, target=15.0))
    clock.advance(6.0)
    p, v = m.position(), m.velocity()
    assert v == pytest.approx(VMAX)
    assert m.handle(cmd(Op.ESTOP, seq=3)) is Reason.ACCEPTED
    assert m.report().state == "estop"
    assert m.handle(cmd(Op.CLEAR_FAULT, seq=4)) is Reason.BUSY       # still rolling
    clock.advance(v / 4.0)
    assert m.velocity() == 0.0
    assert m.position() == pytest.approx(p + v * v / 8.0)
    for refused in (cmd(Op.MOVE, target=3.0), cmd(Op.HOME)):
        assert m.handle(refused) is Reason.IN_ESTOP
    stopped_at = m.position()
    clock.advance(60.0)
    assert m.position() == stopped_at and m.state == "estop"
    assert m.handle(cmd(Op.CLEAR_FAULT, seq=5)) is Reason.ACCEPTED
    st = m.report()
    assert (st.state, st.homed, st.seq) == ("idle", True, 5)
    assert m.handle(cmd(Op.MOVE, target=3.0)) is Reason.ACCEPTED


def test_estop_from_every_state_is_accepted():
    m, clock = motor(start_m=2.0)
    assert m.handle(cmd(Op.ESTOP)) is Reason.ACCEPTED and m.state == "estop"      # unhomed
    m.handle(cmd(Op.CLEAR_FAULT))
    assert m.state == "unhomed"
    m.handle(cmd(Op.HOME))
    clock.advance(1.0)
    assert m.handle(cmd(Op.ESTOP)) is Reason.ACCEPTED and m.state == "estop"      # homing
    clock.advance(1.0)
    m.handle(cmd(Op.CLEAR_FAULT))
    assert m.state == "unhomed" and not m.report().homed   # an interrupted homing does not count
    m.inject_fault(Fault.OVERTEMP)
    assert m.handle(cmd(Op.ESTOP)) is Reason.ACCEPTED and m.state == "estop"      # fault


def test_stop_decelerates_at_the_normal_rate_then_idles():
    m, clock = homed_motor()
    m.handle(cmd(Op.MOVE, target=20.0))
    clock.advance(8.0)
    p, v = m.position(), m.velocity()
    m.handle(cmd(Op.STOP))
    clock.advance(v / ACCEL / 2)
    assert m.state == "moving"
    clock.advance(v / ACCEL / 2)
    assert m.state == "idle" and not m.report().at_target
    assert m.position() == pytest.approx(p + v * v / (2 * ACCEL))


def test_stall_stops_at_once_and_a_fault_brakes_both_latch():
    m, clock = homed_motor()
    m.handle(cmd(Op.MOVE, target=20.0))
    clock.advance(5.0)
    p = m.position()
    m.inject_stall()
    st = m.report()
    assert (st.state, st.fault_code, st.velocity_m_s, st.position_m) == ("fault", Fault.STALL, 0.0, p)
    assert m.handle(cmd(Op.MOVE, target=1.0)) is Reason.IN_FAULT
    assert m.handle(cmd(Op.CLEAR_FAULT)) is Reason.ACCEPTED
    assert m.report().fault_code == 0 and m.state == "idle"
    m.handle(cmd(Op.MOVE, target=20.0))
    clock.advance(5.0)
    m.inject_fault(Fault.OVERCURRENT)
    assert m.velocity() > 0.5                              # braking, not teleported to rest
    clock.advance(1.0)
    assert m.velocity() == 0.0 and m.report().fault_code == Fault.OVERCURRENT


def test_position_is_exact_at_any_query_instant_whatever_the_order():
    m, clock = homed_motor()
    t0 = clock.now()
    m.handle(cmd(Op.MOVE, target=12.0))
    times = t0 + np.array([13.0, 0.5, 7.25, 2.0, 11.0])
    got = np.array([m.position(t) for t in times])
    np.testing.assert_allclose(got, trapezoid(12.0, VMAX, ACCEL, times - t0), atol=1e-9)


def test_params_are_validated():
    with pytest.raises(ValidationError, match="start_m"):
        SimRailParams(rail_length_m=10.0, start_m=12.0)
    with pytest.raises(ValidationError, match="extra"):
        SimRailParams(max_speed=2.0)
    with pytest.raises(ValidationError):
        SimRailParams(accel_m_s2=0)


def test_position_in_the_past_follows_the_motion_planned_then():
    """A look back over an interval that a later command cut (what the world does with food)."""
    m, clock = homed_motor()
    t0 = clock.now()
    m.handle(cmd(Op.MOVE, seq=2, target=10.0))
    clock.advance(5.0)
    past = np.linspace(t0, t0 + 5.0, 51)
    before = [m.position(t) for t in past]
    m.handle(cmd(Op.MOVE, seq=3, target=2.0))             # turn back in mid-travel
    clock.advance(3.0)
    m.inject_stall()
    assert [m.position(t) for t in past] == before
    assert before[0] == 0.0 and before[-1] == pytest.approx(float(trapezoid(10.0, VMAX, ACCEL, np.array(5.0))))


def test_travel_cuts_the_path_where_it_passes_the_marks():
    m, clock = homed_motor()
    t0 = clock.now()
    m.handle(cmd(Op.MOVE, seq=2, target=4.0))
    clock.advance(3.0)
    m.handle(cmd(Op.MOVE, seq=3, target=1.0))             # at 2 m, 1 m/s: brakes to 3 m, then back
    marks = [0.5, 2.0, 2.5, 9.0]
    pieces = m.travel(t0 - 1.0, t0 + 30.0, marks)
    assert pieces[0][0] == t0 - 1.0 and pieces[-1][1] == t0 + 30.0
    assert all(a < b for a, b, _ in pieces)
    assert all(b == c for (_, b, _), (c, _, _) in zip(pieces, pieces[1:], strict=False))    # they tile
    passings = [b for (_, b, p), (_, _, q) in zip(pieces, pieces[1:], strict=False)
                if any((p - x) * (q - x) < 0 for x in marks)]
    crossed = [x for t in passings for x in marks if abs(m.position(t) - x) < 1e-6]
    assert crossed == [0.5, 2.0, 2.5, 2.5, 2.0]           # out to 3 and back to 1: never 9
    # within a piece the carriage stays on one side of every mark
    for a, b, _ in pieces:
        inside = np.array([m.position(t) for t in np.linspace(a, b, 21)[1:-1]])
        assert all(np.all(inside <= x + 1e-9) or np.all(inside >= x - 1e-9) for x in marks)
    assert m.travel(t0, t0, marks) == []


def test_each_estop_latch_is_recorded_once_with_its_instant():
    from devices.sim.truth import TruthLog
    m, clock = homed_motor()
    m.truth = TruthLog(None)
    m.handle(cmd(Op.MOVE, target=10.0))
    clock.advance(3.0)
    t = clock.now()
    for seq in (0, 7, 0):                      # the lane's seq 0 and a repeat: one latch
        assert m.handle(cmd(Op.ESTOP, seq=seq)) is Reason.ACCEPTED
    assert [e[0] for e in m.estops] == [t] and [r["kind"] for r in m.truth.records] == ["estop"]
    clock.advance(10.0)
    assert m.handle(cmd(Op.MOVE, target=3.0)) is Reason.IN_ESTOP
    assert m.handle(cmd(Op.CLEAR_FAULT, seq=8)) is Reason.ACCEPTED
    assert m.handle(cmd(Op.ESTOP, seq=9)) is Reason.ACCEPTED and len(m.estops) == 2
