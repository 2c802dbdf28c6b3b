"""The guard on Modbus writes: only the map's writable addresses (else exception 02), only values in
the row's range (else 03), nothing at all with ``read_only`` (02); a write is checked whole before
anything is done. Each accepted value becomes an override through
``controller.overrides.apply(command, payload, user=<[scada] identity>, origin="modbus <peer>")``;
an override the controller refuses (feeder in e-stop, ration already fed...) answers 04.

The e-stop coil trips the devices' latches synchronously first (``controller.trip_estop``), then
the override's bookkeeping runs as a task: the reply does not wait for it.
"""
from __future__ import annotations

import asyncio
import logging
import math
from dataclasses import dataclass

from pymodbus.constants import ExcCodes

from controller.scada.register_map import COIL, Entry, Layout
from controller.scada.snapshot import in_slot
from controller.scada.words import decode

log = logging.getLogger("fishfarm.scada")


MAX_AUDITED = 16        # values of a refused write kept in the audit


@dataclass(frozen=True)
class Refusal:
    code: ExcCodes
    command: str         # the override the write meant ("write" where it meant none)
    error: str


class Guard:
    def __init__(self, lay: Layout, farm_cfg, scada_cfg, controller, coordinator):
        self.lay, self.farm, self.scada = lay, farm_cfg, scada_cfg
        self.controller, self.coordinator = controller, coordinator
        self.writable = {kind: {e.address: e for e in lay.by_kind(kind) if e.row.write is not None}
                         for kind in (COIL, "holding register")}
        self.accepted = self.refused = 0
        self._tasks: set[asyncio.Task] = set()

    # -- checking -----------------------------------------------------------------------------
    def check(self, kind: str, address: int, values: list) -> list[tuple[Entry, object]] | Refusal:
        """The (entry, value) pairs a write means, or the refusal of all of it."""
        if self.scada.read_only:
            return Refusal(ExcCodes.ILLEGAL_ADDRESS, self.meant(kind, address), "the SCADA server is read-only")
        at, plan, i = self.writable.get(kind, {}), [], 0
        if not values:
            return Refusal(ExcCodes.ILLEGAL_VALUE, "write", "no value")
        while i < len(values):
            e = at.get(address + i)
            if e is None:
                return Refusal(ExcCodes.ILLEGAL_ADDRESS, "write", f"{kind} {address + i}: not writable")
            if i + e.words > len(values):
                return Refusal(ExcCodes.ILLEGAL_ADDRESS, e.row.write.command,
                               f"{e.name}: half of a {e.words}-word value")
            value = self._value(e, values[i:i + e.words])
            if value is None:
                return Refusal(ExcCodes.ILLEGAL_VALUE, e.row.write.command,
                               f"{e.name}: value {values[i:i + e.words]} not accepted")
            plan.append((e, value))
            i += e.words
        return plan

    def meant(self, kind: str, address: int) -> str:
        """The override a write at ``address`` means, "write" where it means none."""
        e = self.writable.get(kind, {}).get(address)
        return "write" if e is None else e.row.write.command

    def _value(self, e: Entry, words: list):
        """The value written, or None when the row does not take it."""
        row = e.row
        if row.dtype == "bool":
            on = bool(words[0])
            # e-stop, reset and acknowledge are commands: 0 would claim a release they cannot give
            return on if on or row.write.command == "pause" else None
        value = decode(row.dtype, [int(w) & 0xFFFF for w in words], row.scale, self.scada.word_order)
        if value is None or not math.isfinite(value):
            return None
        lo, hi = row.write.limits(self.farm)
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            return None
        return value

    # -- acting -------------------------------------------------------------------------------
    async def refused_read(self, kind: str, address: int, values: list, peer: str, code: ExcCodes,
                           error: str) -> None:
        """A read/write (FC 23) refused for its read range before its write was looked at: audited
        as every refused write is, with the command its write meant."""
        self.refused += 1
        received = {"table": kind, "address": address, "values": [int(v) for v in values[:MAX_AUDITED]]}
        self.controller.overrides.refused_on_wire(self.meant(kind, address), f"{error} (exception {int(code):02X})",
                                                  self.scada.identity, received, origin=f"modbus {peer}")

    async def write(self, kind: str, address: int, values: list, peer: str, *,
                    tripped: bool = False) -> ExcCodes | None:
        """``tripped``: the connection already tripped the latches for this very frame."""
        plan = self.check(kind, address, values)
        received = {"table": kind, "address": address, "values": [int(v) for v in values[:MAX_AUDITED]]}
        if isinstance(plan, Refusal):
            self.refused += 1
            # audited as every refusal is, with the write as received (its first words)
            self.controller.overrides.refused_on_wire(
                plan.command, f"{plan.error} (exception {int(plan.code):02X})", self.scada.identity,
                received, origin=f"modbus {peer}")
            return plan.code
        self.accepted += 1
        origin = f"modbus {peer}"
        stopped = False
        for i, (entry, value) in enumerate(plan):
            if entry.row.write.command == "reset" and stopped:
                # an HMI writing its coil block with a stale reset of 1 released the e-stop it sent: the
                # latch never held. The e-stop stands; the reset is a write of its own (exception 04)
                self.controller.overrides.refused_on_wire(
                    "reset", "in the same write as an e-stop: a reset is a write of its own (exception 04)",
                    self.scada.identity, received, origin=origin)
                self.coordinator.refresh()
                return ExcCodes.DEVICE_FAILURE
            if not await self._act(entry, value, origin, last=i == len(plan) - 1, tripped=tripped):
                return ExcCodes.DEVICE_FAILURE
            stopped = stopped or entry.row.write.command == "estop"
        self.coordinator.refresh()
        return None

    async def estop_unanswered(self, peer: str) -> bool:
        """The bookkeeping of an e-stop frame whose latches were tripped as it arrived, on a connection
        closed before its request was answered: the stop stands, and status and the audit say so."""
        base = {"operator": self.scada.identity,
                "reason": "SCADA e-stop frame (its connection closed before the reply)"}
        return await self._apply("estop", base, f"modbus {peer}")

    async def _act(self, e: Entry, value, origin: str, last: bool = True, tripped: bool = False) -> bool:
        who = self.scada.identity
        base = {"operator": who, "reason": f"SCADA write to {e.name}"}
        command = e.row.write.command
        if command == "estop":
            if not tripped:
                self.controller.trip_estop(f"modbus e-stop by {who}")     # the latches first, at once
            if not last:            # what the same write asks next comes after the stop (a reset is refused)
                await self._apply("estop", base, origin)
            else:                   # the reply does not wait for the bookkeeping
                self._later(self._apply("estop", base, origin))
            return True
        if command == "pause":
            return await self._apply("pause" if value else "resume", {**base, "tank": e.label}, origin)
        if command == "start-survey":
            return await self._apply(command, {**base, "tank": e.label}, origin)
        if command in ("feed", "ration"):
            return await self._apply(command, {**base, "tank": e.label, "grams": float(value)}, origin)
        if command == "ack" and e.label is None:
            return await self._apply("ack", {**base, "all": True}, origin)
        if command == "ack":            # an alarm slot: each of its standing sources
            status = self.coordinator.last_status or {}
            sources = sorted({a["source"] for a in status.get("alarms", []) if in_slot(a.get("source", ""), e.label)})
            if not sources:     # a press on a quiet slot: nothing to do, and the audit says so
                self.controller.overrides.noted("ack", {**base, "slot": e.label},
                                                {"ok": True, "acked": [], "note": f"nothing in slot {e.label}"},
                                                user=self.scada.identity, origin=origin)
                return True
            results = [await self._apply("ack", {**base, "source": s}, origin) for s in sources]
            return all(results)
        return await self._apply(command, base, origin)      # reset

    async def _apply(self, command: str, payload: dict, origin: str) -> bool:
        try:
            reply = await self.controller.overrides.apply(command, payload, user=self.scada.identity, origin=origin)
        except Exception:
            log.exception("scada: override %s failed", command)
            return False
        if not reply.get("ok"):
            log.warning("scada: %s from %s refused: %s", command, origin, reply.get("error"))
            return False
        return True

    def _later(self, coro) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)


__all__ = ["Guard"]
