"""The controller as overrides see it, for override tests: real config, clock, ledger, rations and
alarms; the robot a recorder, so "nothing acted on" is checked, not assumed."""
from __future__ import annotations

from controller.alarms import Alarms
from controller.config import Config, FeedingConfig, TankConfig
from controller.feeding.rations import Rations, load_species
from devices.clock import ManualClock

FEEDING = FeedingConfig(portion_g=60.0, min_portion_g=5.0)
TANKS = ("T1", "T2", "12")
STOCK = 2000


class Robot:
    """What the real robot offers overrides, recording every call."""

    def __init__(self):
        self.state, self.pending, self.calls = "idle", {}, []
        self.dispensing = self

    def portion(self, tank, grams):
        return grams

    def on_demand(self, job):
        self.calls.append(("on_demand", job.tank, job.grams, job.source))

    manual_asked = False

    def set_manual(self, on):
        self.calls.append(("set_manual", on))

    def operator_reset(self):
        self.calls.append(("operator_reset",))

    def pause(self, tank):
        self.calls.append(("pause", tank))

    def resume(self, tank):
        self.calls.append(("resume", tank))


class Farm:
    """The controller as overrides see it: config, clock, robot, rations, tanks."""

    def __init__(self, store):
        tanks = [TankConfig(id=t, stock=STOCK, mean_weight_g=20, position_m=3.0 + i, sensors=[f"s{i}"])
                 for i, t in enumerate(TANKS)]
        self.cfg = Config(tanks=tanks, feeding=FEEDING, path="<test>")
        self.clock = ManualClock()
        self.robot = Robot()
        self.store = store
        self.rations = Rations(self.cfg, load_species(), store)
        self.sensor_tank = {s: t.id for t in tanks for s in t.sensors}
        self.published, self.estops, self.tripped = [], [], []
        self.alarms = Alarms(store, lambda *a, **k: None, self.clock)

    def publish_ration(self, tank):
        self.published.append(tank)

    def trip_estop(self, reason="operator e-stop"):     # from the Zenoh thread, before the payload is read
        self.tripped.append(reason)

    async def emergency_stop(self, reason):       # as Controller.emergency_stop before the robot is up
        self.estops.append(reason)
        self.alarms.raise_("estop", f"emergency stop: {reason}", "critical", kind="latched")
        return True                               # both latches confirmed

    def status(self):
        return {"t": self.clock.iso(), "alarms": self.alarms.listing()}

    def acted(self) -> list:
        """Everything an override can change: robot calls, publishes, e-stops, and the ledger's
        rations, stock events, paused tanks and alarm states (acknowledgements)."""
        rows = [tuple(r) for table in ("ration", "stock_event", "tank_pause", "alarm_state")
                for r in self.store.db.execute(f"SELECT * FROM {table}")]
        return [*self.robot.calls, *self.published, *self.estops, *rows]


