"""The controller hearing its fish: the contact hub read, each contact stamped and filtered, the
filter's events (demands, sensor faults) turned into ledger rows, jobs and alarms, and a lost hub
reopened. A mixin of ``controller.app.Controller`` (its devices, clocks, filter, store, robot, bus,
alarms and ``_pause``/``_new_driver``).
"""
from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging

from controller import shutdown
from controller.demand import Demand, SensorFault, SensorRecovered, SlowFishUndetectable
from controller.feeding.robot import Job
from controller.ledger_writes import LedgerUnwritable
from controller.pace import mind_contacts
from devices.errors import DeviceError

log = logging.getLogger("fishfarm")

REOPEN_BACKOFF_S = (0.5, 1.0, 2.0, 5.0)


class Hearing:
    async def _contacts_loop(self) -> None:
        publish = self.bus.publish if self.cfg.bus.publish_contacts else None
        while not self.stopping.is_set():
            try:
                batch = await self.contacts.read()
                # only what the loss raised: the hub clock's alarms stand until its stamps agree
                self.alarms.clear(f"device/{self.contacts.name}", "contacts back", kind="unreachable")
            except DeviceError as exc:
                self.contacts_waiting = 0.0         # (a lost hub is no backlog to wait for)
                self.alarms.raise_(f"device/{self.contacts.name}", exc.text, kind="unreachable")
                await self._reopen(self.contacts)
                continue
            mind_contacts(self, batch)
            for contact in batch:
                tank = self.sensor_tank.get(contact.sensor)
                if tank is None:
                    if contact.sensor not in self.unknown_sensors:
                        self.unknown_sensors.add(contact.sensor)
                        log.warning("contact from unknown sensor %r ignored", contact.sensor)
                    continue
                t = self.hub_clock.stamp(contact.t)
                if t is None:              # stale: a stalled hub's backlog (hub_clock.py)
                    continue
                if publish is not None:
                    publish(f"tank/{tank}/contact", {"t": self.clock.iso(t), "sensor": contact.sensor})
                for event in self.filter.on_contact(t, tank, contact.sensor):
                    self._on_filter_event(event)

    async def _reopen(self, device) -> None:
        """Reconnect the contact hub with back-off until it answers or the controller stops. The
        loss was alarmed by the caller and the first good read clears it; retries log at debug."""
        with contextlib.suppress(Exception):
            await asyncio.wait_for(device.close(), shutdown.CLOSE_DEVICE_S)
        name = device.name
        for attempt in itertools.count():
            await self._pause(REOPEN_BACKOFF_S[min(attempt, len(REOPEN_BACKOFF_S) - 1)])
            if self.stopping.is_set():
                return
            fresh = self._new_driver(device)
            try:
                await fresh.open()
            except DeviceError as exc:
                log.debug("%s: reconnect attempt %d failed: %s", name, attempt + 1, exc.text)
                continue
            if self.stopping.is_set():                # stop() may have closed the devices meanwhile
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(fresh.close(), shutdown.CLOSE_DEVICE_S)
                return
            self.devices[name] = fresh
            for count in self.contacts_carried:
                self.contacts_carried[count] += getattr(device, count, 0)
            self.contacts = fresh
            # debug: a port that opens but stays silent is reopened every few seconds for as long as
            # it lasts; the recovery is said once, by the first good read clearing the alarm
            log.debug("%s reopened after %d attempt(s)", name, attempt + 1)
            return

    def _on_filter_event(self, event) -> None:
        if isinstance(event, Demand):
            if hasattr(self.clock, "busy"):   # an elastic clock: slow from this instant, not the pacer's next look
                self.clock.busy(why="demand raised")
            log.info("demand from %s at %.1f contacts/s, heard %.1f s after", event.tank, event.rate_hz,
                     self.clock.now() - event.t)
            try:
                demand_id = self.store.add_demand(event.tank, event.t, event.rate_hz)
            except LedgerUnwritable:          # the ledger alarm stands: a demand unrecorded is not served
                log.warning("demand from %s not served: the ledger cannot be written", event.tank)
                return
            self.bus.publish(f"tank/{event.tank}/demand",
                             {"t": self.clock.iso(event.t), "rate_hz": round(event.rate_hz, 3)}, reliable=True)
            self.robot.on_demand(Job(event.tank, event.t, demand_id))
        elif isinstance(event, SensorFault):
            self.alarms.raise_(f"sensor/{event.sensor}", f"tank {event.tank}: sensor {event.sensor} {event.kind}",
                               kind=event.kind)
        elif isinstance(event, SensorRecovered):
            self.alarms.clear(f"sensor/{event.sensor}", f"tank {event.tank}: sensor {event.sensor} recovered")
        elif isinstance(event, SlowFishUndetectable):     # once per tank: the filter tells it once
            self.alarms.raise_(f"demand/{event.tank}", f"tank {event.tank}: slow fish undetectable: {event.note}")
