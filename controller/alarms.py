"""Alarms: raised and cleared by source, stored, published, and logged once each way.

A device that goes away is logged once when lost and once when back (Home Assistant's
rule), however many times the loop notices in between.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

log = logging.getLogger("fishfarm.alarm")


@dataclass(frozen=True)
class Alarm:
    source: str
    severity: str       # info | warning | critical
    text: str
    t: float


class Alarms:
    def __init__(self, store, publish, clock):
        self.store = store
        self.publish = publish
        self.clock = clock
        self.active: dict[str, Alarm] = {}
        for row in store.active_alarms():
            self.active[row["source"]] = Alarm(row["source"], row["severity"], row["text"], row["t"])

    def raise_(self, source: str, text: str, severity: str = "warning") -> bool:
        """Returns True when this is news (not already active with the same text)."""
        current = self.active.get(source)
        if current is not None and current.text == text and current.severity == severity:
            return False
        alarm = Alarm(source, severity, text, self.clock.now())
        self.active[source] = alarm
        self._record(alarm, True)
        (log.error if severity == "critical" else log.warning)("%s: %s", source, text)
        return True

    def clear(self, source: str, text: str = "cleared") -> bool:
        current = self.active.pop(source, None)
        if current is None:
            return False
        self._record(Alarm(source, current.severity, text, self.clock.now()), False)
        log.info("%s: %s", source, text)
        return True

    def _record(self, alarm: Alarm, active: bool) -> None:
        self.store.add_alarm(alarm.source, alarm.t, alarm.severity, alarm.text, active)
        self.publish(f"alarm/{alarm.source}", {"t": self.clock.iso(alarm.t), "severity": alarm.severity,
                                               "text": alarm.text, "active": active}, reliable=True)
