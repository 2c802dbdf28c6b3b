"""Alarms: keyed by source and kind, stored, published, acknowledged, logged once each way.

An alarm is one condition — ``(source, kind)``, e.g. ``("device/rail", "unreachable")`` — not one
text, and one alarm for ever: severity, active or cleared, acknowledged (by whom, when), first and
last seen, and a count of the times it was raised (ISA-18.2's model, as SCADA packages show it).
Raising it again while it stands, with new figures in its text ("no status frame for 0.53 s",
then "0.61 s"), counts one more raise and refreshes the text shown in ``status``: no history row,
no publish, no log line. A row in the ``alarm`` history and a reliable publish on
``alarm/{source}`` happen when the condition is raised, when its severity changes, and when it is
cleared — so a device retried every half second for a night is two rows, not eighty thousand, and
one alarm with a count of eighty thousand. An acknowledgement is published too. Raised anew (from
cleared, or at another severity) an alarm is unacknowledged again; acknowledged while standing it
stays standing. ``status`` lists the standing alarms and the cleared ones nobody acknowledged.
A device that goes away is logged once when lost and once when back (Home Assistant's rule).

Texts come from devices, payloads and operators: each is escaped and cut to ``TEXT_MAX``
characters (controller.text), so no alarm forges a log line or swells ``status``.
"""
from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace

from controller.ledger_writes import LedgerUnwritable
from controller.text import printable

log = logging.getLogger("fishfarm.alarm")

GENERAL = "general"
"""The kind of an alarm raised without one: the source's single condition."""
TEXT_MAX = 300
SEVERITIES = ("info", "warning", "critical")
SAVE_REPEATS_S = 60.0
"""Clock seconds between writes of a standing alarm's count and last seen while it repeats."""


@dataclass(frozen=True)
class Alarm:
    source: str
    severity: str       # info | warning | critical
    text: str           # the latest text
    t: float            # when raised (or its severity last changed, or cleared)
    kind: str = GENERAL
    t_text: float | None = None   # when the text was last refreshed
    repeats: int = 0    # raised again while standing, since t
    active: bool = True
    first_t: float | None = None  # first raised, ever (this ledger)
    last_t: float | None = None   # last raised (a repeat too)
    count: int = 1      # times raised, repeats while standing included
    acked_by: str | None = None
    acked_t: float | None = None

    @property
    def key(self) -> tuple[str, str]:
        return self.source, self.kind

    @property
    def acked(self) -> bool:
        return self.acked_t is not None


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
        self.known: dict[tuple[str, str], Alarm] = {}   # every alarm ever raised, standing or cleared
        self._saved_t: dict[tuple[str, str], float] = {}
        self._unsaved: set[tuple[str, str]] = set()      # repeats held back (SAVE_REPEATS_S)
        self._unwritten: dict[tuple[str, str], bool] = {}  # changes the ledger could not take: history?
        for row in store.alarm_states():
            alarm = Alarm(row["source"], row["severity"], row["text"], row["t"], row["kind"],
                          active=bool(row["active"]), first_t=row["first_t"], last_t=row["last_t"],
                          count=row["count"], acked_by=row["acked_by"], acked_t=row["acked_t"])
            self.known[alarm.key] = alarm
            if alarm.active:
                self.active._set(alarm)

    def raise_(self, source: str, text: str, severity: str = "warning", *, kind: str = GENERAL) -> bool:
        """Raise ``(source, kind)``. Returns True when this is news: the alarm was not standing, or
        stood at another severity (then it is stored, published and logged, and unacknowledged
        again); otherwise it counts one more raise and its text is refreshed."""
        if severity not in SEVERITIES:   # raising an alarm never fails: a misspelt severity is loud
            severity = "critical"
        text, now = printable(text, TEXT_MAX), self.clock.now()
        current = self.active.get((source, kind))
        if current is not None and current.severity == severity:
            refreshed = dict(text=text, t_text=now, repeats=current.repeats + 1) if current.text != text else {}
            self._keep(replace(current, last_t=now, count=current.count + 1, **refreshed), news=False)
            return False
        before = self.known.get((source, kind))
        alarm = Alarm(source, severity, text, now, kind, first_t=before.first_t if before else now,
                      last_t=now, count=before.count + 1 if before else 1)
        self._keep(alarm, news=True, history=True)
        self._publish(alarm)
        (log.error if severity == "critical" else log.warning)("%s: %s", source, text)
        return True

    def retext(self, source: str, text: str, *, kind: str = GENERAL) -> bool:
        """The standing ``(source, kind)``'s text refined (an e-stop's provisional reason named, a
        latch confirmed): no raise, so no count. Returns whether it stood. Refined by ``raise_``, one
        e-stop counted two or three."""
        current = self.active.get((source, kind))
        if current is None:
            return False
        text = printable(text, TEXT_MAX)
        if current.text != text:
            self._keep(replace(current, text=text, t_text=self.clock.now()), news=False)
        return True

    def clear(self, source: str, text: str = "cleared", *, kind: str | None = None) -> bool:
        """Clear ``(source, kind)``, or with ``kind=None`` every alarm of ``source``. Returns True
        when something stood. A cleared alarm stays acknowledged or not, as it was."""
        keys = [(source, kind)] if kind is not None else [a.key for a in self.active.of(source)]
        text, cleared = printable(text, TEXT_MAX), False
        for key in keys:
            current = self.active.get(key)
            if current is None:
                continue
            cleared = True
            alarm = replace(current, text=text, t=self.clock.now(), active=False, t_text=None, repeats=0)
            self._keep(alarm, news=True, history=True)
            self._publish(alarm)
            log.info("%s: %s", source, text)
        return cleared

    def ack(self, by: str, source: str | None = None, kind: str | None = None) -> list[Alarm]:
        """Acknowledge the unacknowledged alarms of ``source`` (one ``kind``, or every kind), or of
        every source with ``source=None``: standing ones stay standing. Returns those acknowledged;
        LookupError when ``source`` (or that kind of it) never raised an alarm."""
        keys = [k for k in self.known if source is None or (k[0] == source and kind in (None, k[1]))]
        if source is not None and not keys:
            raise LookupError(source if kind is None else f"{source} {kind}")
        now, by, done = self.clock.now(), printable(by, TEXT_MAX), []
        for key in keys:
            alarm = self.known[key]
            if alarm.acked:
                continue
            alarm = replace(alarm, acked_by=by, acked_t=now)
            self._keep(alarm, news=True)
            self._publish(alarm)
            log.info("%s %s acknowledged by %s", alarm.source, alarm.kind, by)
            done.append(alarm)
        return done

    def listing(self) -> list[dict]:
        """The alarms ``status`` shows: standing ones, and cleared ones nobody acknowledged yet;
        standing first, then most severe first, then oldest first."""
        rank = {s: i for i, s in enumerate(reversed(SEVERITIES))}
        shown = [a for a in self.known.values() if a.active or not a.acked]
        alarms = sorted(shown, key=lambda a: (not a.active, rank.get(a.severity, 0), a.t))
        return [{"source": a.source, "repeats": a.repeats, **self._fields(a)} for a in alarms]

    def _fields(self, a: Alarm) -> dict:
        iso = self.clock.iso
        return {"kind": a.kind, "severity": a.severity, "text": a.text, "t": iso(a.t), "active": a.active,
                "count": a.count, "first_t": iso(a.first_t if a.first_t is not None else a.t),
                "last_t": iso(a.last_t if a.last_t is not None else a.t), "acked": a.acked,
                "acked_by": a.acked_by, "acked_t": None if a.acked_t is None else iso(a.acked_t)}

    def _keep(self, alarm: Alarm, *, news: bool, history: bool = False) -> None:
        """Hold ``alarm`` and write its state (with a ``history`` row, in the same commit): at once
        when ``news``; a repeat at most every ``SAVE_REPEATS_S`` (a device retried twice a second
        must not cost an fsync each time: a crash loses at most that long of a standing alarm's
        count)."""
        self.known[alarm.key] = alarm
        if alarm.active:
            self.active._set(alarm)
        else:
            self.active._pop(alarm.key)
        if not news and alarm.last_t - self._saved_t.get(alarm.key, alarm.t) < SAVE_REPEATS_S:
            self._unsaved.add(alarm.key)
            return
        self._save(alarm, history)

    def flush(self) -> bool:
        """Write the repeats not written yet (a clean stop calls it before closing the ledger), and
        the changes an unwritable ledger refused. True when nothing is left unwritten."""
        for key, history in sorted(self._unwritten.items()):
            self._save(self.known[key], history)
        for key in sorted(self._unsaved):
            self._save(self.known[key])
        return not self._unwritten

    def _save(self, alarm: Alarm, history: bool = False) -> None:
        """Write the alarm's state. A ledger that cannot take it (a full disk: the ``ledger`` alarm
        says so) does not stop the alarm: it stands, is published and logged, and a later
        ``flush`` writes its latest state (with one history row for the changes meanwhile)."""
        self._unsaved.discard(alarm.key)
        history = self._unwritten.pop(alarm.key, False) or history
        try:
            self.store.save_alarm_state(source=alarm.source, kind=alarm.kind, severity=alarm.severity,
                                        text=alarm.text, active=alarm.active, t=alarm.t,
                                        first_t=alarm.first_t if alarm.first_t is not None else alarm.t,
                                        last_t=alarm.last_t if alarm.last_t is not None else alarm.t,
                                        count=alarm.count, acked_by=alarm.acked_by, acked_t=alarm.acked_t,
                                        history=history)
        except LedgerUnwritable:
            self._unwritten[alarm.key] = history
            return
        self._saved_t[alarm.key] = alarm.last_t if alarm.last_t is not None else alarm.t

    def _publish(self, alarm: Alarm) -> None:
        self.publish(f"alarm/{alarm.source}", self._fields(alarm), reliable=True)
