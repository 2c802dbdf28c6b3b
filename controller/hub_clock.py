"""The contact hub's time stamps, held to the controller's clock.

The demand filter counts contacts by the hub's own stamps (a batch read late still has its
contacts' times). A hub whose clock is off breaks that: one stamp 600 s ahead moved a tank's
slots past every contact that followed, and a clock stepped 300 s back put every later contact in
the past: the tank raised no demand, and nobody was told. A stamp further than ``SKEW_WALL_S``
of wall time from the controller's clock (whatever the farm clock's speed) is one of:

- **ahead**: no contact arrives before it happens: the hub's clock is wrong. The stamp is
  replaced by the time it arrived, and the clock alarmed (``device/{hub}``, kind ``clock``) once,
  cleared once its stamps agree again;
- **behind, by a lag that holds or grows** for ``LAG_HOLDS_WALL_S`` of arrivals: a clock set back,
  or one running slower than the controller's (a simulator at another ``--speed``). From then on,
  as ahead;
- **behind, by a lag that does not hold**: contacts late, not a clock off — a hub (or a link, or a
  simulator) stalled and now sending what it held, its lag shrinking as it catches up. Counted at
  their arrival, hours of contacts made one burst, and fish that had stopped asking were fed (23
  demands outside any episode after a 30 s stall). They are dropped as stale (``late``), alarmed
  once (kind ``late``), cleared once stamps agree again: fish still hungry go on asking.
"""
from __future__ import annotations

SKEW_WALL_S = 10.0       # a batch is read well within this; a hub clock off by more is wrong
LAG_HOLDS_WALL_S = 2 * SKEW_WALL_S   # a lag held this long (wall, by arrival) is a clock set back


class HubClock:
    def __init__(self, clock, alarms, hub: str):
        self.clock, self.alarms, self.hub = clock, alarms, hub
        self.off = False
        self.replaced = 0         # stamps replaced by their arrival time
        self.late = 0             # stale contacts dropped
        self._lag: tuple[float, float] | None = None    # (arrival, lag) the lag seen since
        self._late_said = False

    def stamp(self, t: float) -> float | None:
        """The time a contact stamped ``t`` by the hub is counted at; None: too late to count."""
        now = self.clock.now()
        skew = t - now
        if self._apart(t, now) <= SKEW_WALL_S:
            self._agrees()
            return t
        if skew < 0 and not self.off and not self._lag_holds(now, -skew):
            self.late += 1
            if not self._late_said:
                self._late_said = True
                self.alarms.raise_(f"device/{self.hub}", f"contacts arriving {-skew:.0f} s late (the hub or its "
                                   "link stalled?): not counted, the fish ask again", kind="late")
            return None
        self.replaced += 1
        if not self.off:
            self.off = True
            self.alarms.raise_(f"device/{self.hub}", f"the hub's clock is {skew:+.0f} s off the controller's: "
                               "contacts counted at their arrival", kind="clock")
        return now

    def heard(self, t: float | None) -> None:
        """The hub's newest stamp, a heartbeat's included (the driver's ``stream_t``): a standing
        ``clock`` or ``late`` alarm clears once it agrees — without it they stood until a fish
        bumped a sensor (at night, for hours). Raises nothing: a contact's stamp does that."""
        if t is None or not (self.off or self._late_said):
            return
        if self._apart(t, self.clock.now()) <= SKEW_WALL_S:
            self._agrees()

    def _lag_holds(self, now: float, lag: float) -> bool:
        """Whether contacts have been at least this far behind, less SKEW_WALL_S, for LAG_HOLDS_WALL_S:
        a lag that holds (a clock set back) or grows (a hub clock slower than ours: a simulator at
        another --speed, whose contacts were all dropped as late while the lag grew by hours). Only
        a lag that shrinks is a backlog catching up."""
        shrunk = None if self._lag is None else self._lag[1] - lag
        if shrunk is None or (shrunk > 0 and self.clock.wall(shrunk) > SKEW_WALL_S):
            self._lag = (now, lag)
        return self.clock.wall_since(self._lag[0]) >= LAG_HOLDS_WALL_S

    def _apart(self, t: float, now: float) -> float:
        """Wall seconds between stamp ``t`` and ``now``: ahead, as the clock will take them; behind,
        as they passed (``wall_since``) -- not ``wall`` of the lag, which converts at the speed now: on
        an elastic clock a lag run up at 60,000x, read at 60x, was 17 s for 17 ms, and every contact
        of a fast span was dropped as stale, 300 alarms a run."""
        return self.clock.wall(t - now) if t >= now else self.clock.wall_since(t)

    def _agrees(self) -> None:
        self._lag = None
        if self.off:
            self.off = False
            self.alarms.clear(f"device/{self.hub}", "the hub's clock agrees again", kind="clock")
        if self._late_said:
            self._late_said = False
            self.alarms.clear(f"device/{self.hub}", "contacts on time again", kind="late")
