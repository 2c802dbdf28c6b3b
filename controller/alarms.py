"""Alarms: keyed by source and kind, stored, published, and logged once each way.

An alarm is one condition — ``(source, kind)``, e.g. ``("device/rail", "unreachable")`` — not one
text. Raising it again while it stands, with new figures in its text ("no status frame for
0.53 s", then "0.61 s"), only refreshes the text shown in ``status``: no ledger row, no publish,
no log line. A row in the ``alarm`` table and a reliable publish on ``alarm/{source}`` happen when
the condition is raised, when its severity changes, and when it is cleared — so a device retried
every half second for a night is two rows, not eighty thousand. A device that goes away is
logged once when lost and once when back (Home Assistant's rule).

Texts come from devices, payloads and operators: each is escaped and cut to ``TEXT_MAX``
characters (controller.text), so no alarm forges a log line or swells ``status``.
"""
from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace

from controller.text import printable

log = logging.getLogger("fishfarm.alarm")

GENERAL = "general"
"""The kind of an alarm raised without one: the source's single condition."""
TEXT_MAX = 300
SEVERITIES = ("info", "warning", "critical")


@dataclass(frozen=True)
class Alarm:
    source: str
    severity: str       # info | warning | critical
    text: str           # the latest text
    t: float            # when raised (or its severity last changed)
    kind: str = GENERAL
    t_text: float | None = None   # when the text was last refreshed
    repeats: int = 0    # raised again while standing, since t

    @property
    def key(self) -> tuple[str, str]:
        return self.source, self.kind


class ActiveAlarms(Mapping):
    """The standing alarms by ``(source, kind)``. A bare source works too: ``source in active``
    asks whether any alarm of that source stands, ``active[source]`` is its most severe (then
    latest) one."""

    def __init__(self):
        self._by_key: dict[tuple[str, str], Alarm] = {}

    def __getitem__(self, key: tuple[str, str] | str) -> Alarm:
        if isinstance(key, str):
            alarms = self.of(key)
            if not alarms:
                raise KeyError(key)
            return max(alarms, key=lambda a: (SEVERITIES.index(a.severity), a.t))
        return self._by_key[key]

    def __iter__(self) -> Iterator[tuple[str, str]]:
        return iter(self._by_key)

    def __len__(self) -> int:
        return len(self._by_key)

    def __contains__(self, key) -> bool:
        if isinstance(key, str):
            return any(source == key for source, _ in self._by_key)
        return key in self._by_key

    def of(self, source: str) -> list[Alarm]:
        return [a for (s, _), a in self._by_key.items() if s == source]

    def _set(self, alarm: Alarm) -> None:
        self._by_key[alarm.key] = alarm

    def _pop(self, key: tuple[str, str]) -> Alarm | None:
        return self._by_key.pop(key, None)


class Alarms:
    def __init__(self, store, publish, clock):
        self.store = store
        self.publish = publish
        self.clock = clock
        self.active = ActiveAlarms()
        for row in store.active_alarms():
            self.active._set(Alarm(row["source"], row["severity"], row["text"], row["t"], row["kind"]))

    def raise_(self, source: str, text: str, severity: str = "warning", *, kind: str = GENERAL) -> bool:
        """Raise ``(source, kind)``. Returns True when this is news: the alarm was not standing, or
        stood at another severity (then it is stored, published and logged); otherwise only its
        text is refreshed."""
        if severity not in SEVERITIES:   # raising an alarm never fails: a misspelt severity is loud
            severity = "critical"
        text, now = printable(text, TEXT_MAX), self.clock.now()
        current = self.active.get((source, kind))
        if current is not None and current.severity == severity:
            if current.text != text:
                self.active._set(replace(current, text=text, t_text=now, repeats=current.repeats + 1))
            return False
        alarm = Alarm(source, severity, text, now, kind)
        self.active._set(alarm)
        self._record(alarm, True)
        (log.error if severity == "critical" else log.warning)("%s: %s", source, text)
        return True

    def clear(self, source: str, text: str = "cleared", *, kind: str | None = None) -> bool:
        """Clear ``(source, kind)``, or with ``kind=None`` every alarm of ``source``. Returns True
        when something stood."""
        keys = [(source, kind)] if kind is not None else [a.key for a in self.active.of(source)]
        text, cleared = printable(text, TEXT_MAX), False
        for key in keys:
            current = self.active._pop(key)
            if current is None:
                continue
            cleared = True
            self._record(Alarm(source, current.severity, text, self.clock.now(), current.kind), False)
            log.info("%s: %s", source, text)
        return cleared

    def listing(self) -> list[dict]:
        """The standing alarms as ``status`` shows them, most severe first, then oldest first."""
        rank = {s: i for i, s in enumerate(reversed(SEVERITIES))}
        alarms = sorted(self.active.values(), key=lambda a: (rank.get(a.severity, 0), a.t))
        return [{"source": a.source, "kind": a.kind, "severity": a.severity, "text": a.text,
                 "t": self.clock.iso(a.t), "repeats": a.repeats} for a in alarms]

    def _record(self, alarm: Alarm, active: bool) -> None:
        self.store.add_alarm(alarm.source, alarm.t, alarm.severity, alarm.text, active, kind=alarm.kind)
        self.publish(f"alarm/{alarm.source}", {"t": self.clock.iso(alarm.t), "severity": alarm.severity,
                                               "text": alarm.text, "active": active, "kind": alarm.kind},
                     reliable=True)
