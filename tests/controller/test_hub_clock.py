"""The contact hub's stamps held to the controller's clock (controller/hub_clock.py): a hub clock
gone wrong must not blind the demand filter. The contacts are generated here, at 1 a second for two
minutes (a hungry tank, by the contact sensor model), the stamps spoilt as a probe spoilt them."""
from __future__ import annotations

from controller.demand import Demand, DemandFilter
from controller.hub_clock import LAG_HOLDS_WALL_S, SKEW_WALL_S, HubClock

T0 = 1_780_000_000.0


class Clock:
    """Farm time as the test sets it; real time's speed (a farm second is a wall second)."""

    def __init__(self, t: float):
        self.t = t

    def now(self) -> float:
        return self.t

    def wall(self, farm_s: float) -> float:
        return farm_s

    def wall_since(self, farm_t: float) -> float:
        return max(0.0, self.t - farm_t)


class Alarms:
    def __init__(self):
        self.raised, self.cleared = [], []

    def raise_(self, source, text, severity="warning", *, kind="general"):
        self.raised.append((source, kind, text))

    def clear(self, source, text="cleared", *, kind=None):
        self.cleared.append((source, kind))


def episode(start: float, seconds: float = 120.0):
    """A hungry tank's contacts, one a second on alternate sensors, as the hub sends them."""
    return [(start + i, "T1-a" if i % 2 else "T1-b") for i in range(int(seconds))]


def demands_within(contacts, clock: Clock, stamp, until: float) -> list[float]:
    """The demand times of ``contacts`` [(true t, hub stamp, sensor)] fed in order, as the controller does."""
    f = DemandFilter(None, {"T1": ["T1-a", "T1-b"]})
    out = []
    for true_t, hub_t, sensor in contacts:
        clock.t = true_t
        out += [e.t for e in f.on_time(true_t) if isinstance(e, Demand)]
        counted = stamp(hub_t)
        if counted is not None:              # None: a stale contact, dropped
            out += [e.t for e in f.on_contact(counted, "T1", sensor) if isinstance(e, Demand)]
    out += [e.t for e in f.on_time(until) if isinstance(e, Demand)]
    return out


def test_one_stamp_far_ahead_and_a_clock_stepped_back_do_not_blind_the_tank():
    clock, alarms = Clock(T0), Alarms()
    hub = HubClock(clock, alarms, "hub")
    glitch = [(T0 + 10.0, T0 + 610.0, "T1-a")]                          # one line 600 s ahead
    first = [(t, t, s) for t, s in episode(T0 + 30.0)]
    stepped = [(t, t - 300.0, s) for t, s in episode(T0 + 1000.0)]         # the hub's clock 300 s back
    caught = demands_within(glitch + first + stepped, clock, hub.stamp, T0 + 1200.0)
    in_first = [t for t in caught if T0 + 30 <= t <= T0 + 90]
    in_stepped = [t for t in caught if T0 + 1000 <= t <= T0 + 1060]
    assert in_first and in_stepped, caught                            # both within 60 s of their start
    assert alarms.raised[0][:2] == ("device/hub", "clock") and "+600 s off" in alarms.raised[0][2]
    assert ("device/hub", "clock") in alarms.cleared                  # stamps agreed in between
    # a lag that holds LAG_HOLDS_WALL_S is a clock set back: what came before it is dropped as late
    held = int(LAG_HOLDS_WALL_S)
    assert hub.late == held and hub.replaced == 1 + 120 - held
    assert [a[1] for a in alarms.raised] == ["clock", "late", "clock"]


def test_a_stalled_hubs_backlog_is_dropped_not_made_one_burst_of_demand():
    """A hub (or its link, or the simulator) stopped 30 s wall at 360x sends three farm hours of
    contacts at once, correctly stamped. Counted at their arrival they were one burst: a demand for
    fish that had asked hours before, or never (turbulence spread over hours)."""
    speed = 360.0

    class Fast(Clock):
        def wall(self, farm_s: float) -> float:
            return farm_s / speed

        def wall_since(self, farm_t: float) -> float:
            return max(0.0, self.t - farm_t) / speed
    clock, alarms = Fast(T0), Alarms()
    hub = HubClock(clock, alarms, "hub")
    # an episode long ago and turbulence after it: 3 farm hours of stamps, all arriving at T0 + 3 h
    stalled = [(T0 + 3 * 3600.0 + i * 1e-3, t, s) for i, (t, s) in enumerate(episode(T0, 120.0) + [
        (T0 + 600.0 + 60.0 * k, "T1-a") for k in range(170)])]
    assert demands_within(stalled, clock, hub.stamp, T0 + 3 * 3600.0 + 60.0) == []
    stale = sum((arrived - stamped) / speed > SKEW_WALL_S for arrived, stamped, _ in stalled)
    assert stale > 200 and hub.late == stale and hub.replaced == 0     # the last hour's are within tolerance
    assert alarms.raised[0][:2] == ("device/hub", "late") and "late" in alarms.raised[0][2]
    # then the fish ask now, on time: judged as ever, and the alarm clears
    now = [(t, t, s) for t, s in episode(T0 + 3 * 3600.0 + 120.0)]
    assert demands_within(now, clock, hub.stamp, T0 + 4 * 3600.0)
    assert ("device/hub", "late") in alarms.cleared and ("device/hub", "clock") not in alarms.cleared


def test_stamps_within_the_tolerance_are_kept_as_the_hub_gave_them():
    clock, alarms = Clock(T0), Alarms()
    hub = HubClock(clock, alarms, "hub")
    for late in (0.0, 0.5, -SKEW_WALL_S, SKEW_WALL_S):
        assert hub.stamp(T0 + late) == T0 + late
    assert alarms.raised == [] and hub.replaced == 0


def test_heartbeats_that_agree_clear_a_standing_alarm_and_raise_none():
    """The clock and late alarms cleared only with the next contact: at night, with no fish asking,
    they stood for hours while the hub's heartbeats agreed. A heartbeat's stamp raises nothing."""
    clock, alarms = Clock(T0), Alarms()
    hub = HubClock(clock, alarms, "hub")
    hub.heard(T0 + 600.0)                                 # no alarm standing: nothing, whatever it says
    hub.heard(None)
    assert alarms.raised == [] and alarms.cleared == []
    assert hub.stamp(T0 + 600.0) == T0                    # a contact 600 s ahead: the clock alarm
    clock.t = T0 + 60.0
    hub.heard(T0 + 660.0)                                 # heartbeats still ahead: it stands
    assert alarms.cleared == [] and hub.off
    hub.heard(T0 + 60.0 + SKEW_WALL_S / 2)                # the hub's clock set right
    assert alarms.cleared == [("device/hub", "clock")] and not hub.off
    clock.t = T0 + 3600.0
    assert hub.stamp(T0 + 3000.0) is None                 # late contacts: the late alarm
    hub.heard(T0 + 3000.0)
    assert ("device/hub", "late") not in alarms.cleared
    hub.heard(T0 + 3600.0)                                # caught up
    assert alarms.cleared[-1] == ("device/hub", "late")
    assert [a[1] for a in alarms.raised] == ["clock", "late"]


def test_a_hub_clock_slower_than_ours_is_a_clock_off_not_contacts_late_for_ever():
    """A simulator started at --speed 60 beside a controller at 240: its stamps fall behind by 3 farm
    s every farm s. Each contact was dropped as late (the lag never held, it grew), the fish asked
    for four farm hours and were never fed. A lag that grows for LAG_HOLDS_WALL_S is a clock off:
    alarmed as such, contacts counted at their arrival, and the tank's demand raised."""
    clock, alarms = Clock(T0), Alarms()
    hub = HubClock(clock, alarms, "hub")
    start = T0 + 60.0
    slow = [(t, start + 0.25 * (t - start), s) for t, s in episode(start, 180.0)]
    caught = demands_within(slow, clock, hub.stamp, start + 240.0)
    assert caught and caught[0] <= start + 60.0 + LAG_HOLDS_WALL_S, caught
    assert [a[1] for a in alarms.raised] == ["late", "clock"], alarms.raised
    assert hub.replaced > 100 and hub.late < LAG_HOLDS_WALL_S + SKEW_WALL_S + 5


def test_on_an_elastic_clock_a_fast_spans_contacts_read_after_it_slowed_are_on_time(tmp_path):
    """The grow-out's controller read each fast span's contacts some 20 ms of wall after the hub
    stamped them, by then on a clock slowed to 60x: ``wall`` of the lag (1,200 farm s) gave 20 s, and
    every such contact was dropped as a stalled hub's backlog, ~300 late alarms a run. Judged by the
    wall since each stamp, they count; a hub that held its contacts 15 s of wall is still dropped."""
    from devices.elastic_clock import ElasticClock, create

    class Wall:
        t = 5_000.0

        def __call__(self):
            return self.t
    wall, slow, fast = Wall(), 60.0, 60_000.0
    create(tmp_path / "clock", slow=slow, fast=fast, farm_start=T0, wall_time=wall, lease_s=0.0)
    clock = ElasticClock(tmp_path / "clock", wall_time=wall, alive=lambda pid: True)
    clock.claim("controller")
    clock.idle_until(T0 + 1e7)
    alarms = Alarms()
    hub = HubClock(clock, alarms, "hub")
    stamps = []
    for _ in range(100):                       # half a wall second fast: the hub stamps, the controller reads
        wall.t += 0.005
        stamps.append(clock.now())
    clock.busy()                               # then slow, and the last 20 ms of stamps read now
    wall.t += 0.02
    recent = stamps[-10:-2]                    # stamped 30-65 ms of wall ago, 600-2,400 farm s behind
    assert all(clock.wall_since(t) <= 0.07 for t in recent)
    assert all(clock.wall(clock.now() - t) > SKEW_WALL_S for t in recent)
    assert [hub.stamp(t) for t in recent] == recent
    assert alarms.raised == [] and hub.late == 0
    wall.t += 15.0                             # a hub that held what it stamped then for 15 s
    assert hub.stamp(stamps[-1]) is None and hub.late == 1
    assert [a[1] for a in alarms.raised] == ["late"]
