"""The contact hub's time stamps, held to the controller's clock.

The demand filter counts contacts by the hub's own stamps (a batch read late still has its
contacts' times). A hub whose clock is off breaks that: one stamp 600 s ahead moved a tank's
slots past every contact that followed, and a clock stepped 300 s back put every later contact in
the past: the tank raised no demand, and nobody was told. A stamp further than ``SKEW_WALL_S``
of wall time from the controller's clock (whatever the farm clock's speed) is replaced by the
time it arrived, and the hub's clock is alarmed (``device/{hub}``, kind ``clock``) once, cleared
once its stamps agree again.
"""
from __future__ import annotations

SKEW_WALL_S = 10.0       # a batch is read well within this; a hub clock off by more is wrong


class HubClock:
    def __init__(self, clock, alarms, hub: str):
        self.clock, self.alarms, self.hub = clock, alarms, hub
        self.off = False
        self.replaced = 0         # stamps replaced by their arrival time

    def stamp(self, t: float) -> float:
        """The time a contact stamped ``t`` by the hub is counted at."""
        now = self.clock.now()
        skew = t - now
        if self.clock.wall(abs(skew)) <= SKEW_WALL_S:
            if self.off:
                self.off = False
                self.alarms.clear(f"device/{self.hub}", "the hub's clock agrees again", kind="clock")
            return t
        self.replaced += 1
        if not self.off:
            self.off = True
            self.alarms.raise_(f"device/{self.hub}", f"the hub's clock is {skew:+.0f} s off the controller's: "
                               "contacts counted at their arrival", kind="clock")
        return now
