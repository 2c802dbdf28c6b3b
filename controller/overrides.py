"""Operator overrides: one entry, ``Overrides.apply``, for every command from Zenoh
(``farm/{site}/override/{command}`` queryables) or Modbus writes: validate, act, audit, reply.

Payloads are validated strictly (controller.override_models): a refusal is
``{"ok": false, "error": "<field>: <why>"}`` and nothing is done. Nothing is coerced.
``estop`` is never refused: any payload, even an empty or unreadable one, stops the robot. Its
latches are tripped before ``apply`` runs (on the Zenoh thread by the bus, or by the Modbus write
handler); audit rows are written after the reply, so no fsync sits on its path.

Every command, accepted or refused, is one row of the audit (controller.records): who (the
authenticated ``user`` when the transport knows it, and the ``operator`` the payload claims), when,
the command, the payload (escaped, bounded), from where, and the result.
"""
from __future__ import annotations

import asyncio
import logging
import time

from controller.bus_serve import Prepared
from controller.feeding.robot import CONFIRM_WAIT_S, Job
from controller.ledger_writes import LedgerUnwritable
from controller.override_models import (  # noqa: F401
    AUDIT_TEXT_MAX,
    OPERATOR_MAX,
    RATION_MAX_G,
    REASON_MAX,
    STARTING,
    Ack,
    Bare,
    Feed,
    Loss,
    Manual,
    Refused,
    SetRation,
    Settle,
    Tank,
    Transfer,
    claimed,
    parse,
    payload_text,
    received_text,
    who,
)
from controller.override_requests import Once, request_id
from controller.override_tanks import TankCommands
from controller.payload import json_kind
from controller.store import Store
from controller.text import printable

log = logging.getLogger("fishfarm.override")

LOG_LINE_MAX = 1000
AUDIT_HELD_MAX = 10_000      # audit rows held while the ledger cannot be written
HISTORY_AT_ONCE = 2          # history queries answered at once (threads); more wait their turn
STATUS_FRESH_WALL_S = 0.1    # a status snapshot answers every query this long (an override renews it)
NOT_YET: dict[str, str] = {}
NO_CLEANER = "no pond cleaner in this controller (farm.toml has no [cleaning] section)"
COMMANDS = ("estop", "reset", "manual", "feed", "ration", "settle", "pause", "resume", "ack",
            "mortality", "harvest", "transfer", "start-survey", "cleaner-start", "cleaner-stop", "cleaner-return")


def _wall() -> float:
    """The status snapshot's clock (a test freezes this, not the process's time.monotonic)."""
    return time.monotonic()


class _OneLine(logging.Filter):
    """Every line this module logs is one bounded line, whatever an operator's payload held (the
    e-stop logs what it was given, unvalidated)."""

    def filter(self, record: logging.LogRecord) -> bool:
        record.msg, record.args = printable(record.getMessage(), LOG_LINE_MAX), None
        return True


log.addFilter(_OneLine())


class Overrides(TankCommands):
    def __init__(self, controller):
        self.c = controller
        self._rows: list[dict] = []      # audit rows not written yet (this loop turn's)
        self._resetting = asyncio.Lock()
        self._act = {name: getattr(self, name.replace("-", "_")) for name in COMMANDS if name not in NOT_YET}
        self._once = Once(lambda: self.c.store, Refused, LedgerUnwritable)
        self._historians = asyncio.Semaphore(HISTORY_AT_ONCE)
        self._status: tuple[Prepared, float, bool] | None = None   # (snapshot, wall monotonic, e-stop tripped)

    def declare(self, bus) -> None:
        # one queryable on override/*: an unknown command is refused with a reason, not left unanswered
        handlers = {name: self._from_zenoh(name) for name in COMMANDS}
        # estop also trips the latches on the Zenoh thread itself, before the payload is parsed
        bus.overrides(handlers, lenient=("estop",), urgent={"estop": self.c.trip_estop},
                      refused=self.refused_on_wire)
        bus.queryable("status", self.status, lenient=True, ready=self.fresh_status)
        # a range it cannot read is refused, not ignored; so is a key a level short or over (no reply
        # came to history/surveys or history/surveys/T1/extra)
        bus.queryable("history/**", self.history, selector=True)

    def _from_zenoh(self, command: str):
        async def handle(payload, user: str | None = None) -> dict:
            return await self.apply(command, payload, user=user, origin="zenoh")
        return handle

    async def status(self, payload, user: str | None = None) -> dict:
        """The whole snapshot, built and encoded at most every STATUS_FRESH_WALL_S, and answered
        straight from the Zenoh thread while fresh (``fresh_status``): 400 queries a second had
        each built and encoded one on the loop, 70 % busy with them, a Modbus e-stop 2-3 s late and
        a SIGTERM's stop overrunning."""
        snapshot = self.fresh_status()      # queries that came while it was stale, one built for all
        if snapshot is None:
            tripped = self._tripped()
            snapshot = Prepared(self.c.status())
            self._status = (snapshot, _wall(), tripped)
        return snapshot

    def fresh_status(self) -> Prepared | None:
        """On a Zenoh thread: the last snapshot while it is fresh, else None (the loop builds one).
        An e-stop tripped since (from the Modbus coil's or Zenoh's own thread) makes it stale."""
        held = self._status                 # one read: the loop replaces the triple whole
        if held is None or _wall() - held[1] >= STATUS_FRESH_WALL_S or held[2] != self._tripped():
            return None
        return held[0]

    def _tripped(self) -> bool:
        lane = getattr(self.c, "lane", None)
        return bool(lane is not None and lane.tripped)

    async def history(self, payload, *, key: str, params: dict) -> dict:
        """``history/{what}/{tank}?since=...;until=...`` (controller/history.py); the range may
        come in the payload instead ({"since": ..., "until": ...}).

        Answered on a thread of its own, from a read-only connection of its own: 100,000 rows took
        10-18 s on the loop, and a Modbus e-stop waited behind them (11.9 s) while SCADA and
        ``status`` went unanswered. Two at a time; SQLite's write-ahead log lets them read beside
        the controller's writes."""
        from controller.history import query_reply
        both = sorted(set(params) & set(payload))
        if both:              # which one was meant? (the payload won without a word)
            return {"ok": False, "error": f"{both[0]}: given in the selector and in the payload: give it once"}
        store, cfg, asked = self.c.store, self.c.cfg, {**params, **payload}
        now = self.c.clock.now()
        if str(store.path) == ":memory:":          # a ledger in memory: no file to open again
            return query_reply(store, cfg, key, asked, now)

        def answer() -> dict:
            reader = Store.reader(store.path)
            try:
                return query_reply(reader, cfg, key, asked, now)
            finally:
                reader.close()
        async with self._historians:
            return await asyncio.to_thread(answer)

    # ------------------------------------------------------------ the one entry

    async def apply(self, command: str, payload: object, *, user: str | None = None,
                    origin: str = "zenoh") -> dict:
        """Every override, from Zenoh or Modbus: validate, act, audit, reply. Never raises for bad
        input: returns {"ok": False, "error": "<field>: <why>"}. ``user`` is the authenticated
        identity when known and is what the audit names; the payload's ``operator`` is kept as the
        claimed name beside it. ``origin`` says from where, e.g. "zenoh", "modbus 127.0.0.1:53122"."""
        t = self.c.clock.now()
        self._status = None                  # whatever it does shows in the next status
        name = command if isinstance(command, str) else printable(command, 64)
        try:
            if name not in COMMANDS:
                raise Refused(f"command: unknown command {printable(name, 64)!r}; known: {', '.join(COMMANDS)}")
            if payload is not None and not isinstance(payload, dict) and name != "estop":
                raise Refused(f"payload: must be a JSON object, not {json_kind(payload)}")
            if name in NOT_YET:
                parse(Tank if name == "start-survey" else Bare, payload)
                raise Refused(f"not available yet: {NOT_YET[name]}")
            act = self._act[name]
            if name == "estop":     # an e-stop is carried out every time it comes
                reply = await act(payload, user)
            else:
                reply = await self._once.run(name, request_id(payload), t, lambda: act(payload, user), payload)
                if reply.get("repeat") and name == "feed":
                    reply = self._feed_as_it_stands(reply)
        except Refused as exc:
            reply = {"ok": False, "error": str(exc)}
        except LedgerUnwritable as exc:      # said once by the store and the ledger alarm
            reply = {"ok": False, "error": f"ledger: cannot be written ({exc}); try again once it can"}
        except Exception as exc:  # a bug: the operator hears of it, the audit keeps it
            log.exception("override %s failed", name)
            reply = {"ok": False, "error": f"internal error: {type(exc).__name__}"}
        self._status = None                  # and one built while it waited (a reset's cleaner) is not kept
        self._audit(t=t, user=user, command=name, payload=payload, origin=origin, reply=reply)
        return reply

    def refused_on_wire(self, command: str, error: str, user: str | None = None, payload=None, *,
                        origin: str = "zenoh") -> None:
        """The bus refused a query before any handler saw it (an unknown command, an unreadable
        payload), or the SCADA's map a write (an address not writable, a value out of range):
        audited all the same, with the operator the payload claims and the payload as received
        where it was readable. Called on the loop."""
        self._audit(t=self.c.clock.now(), user=user, command=printable(command, 64), payload=payload,
                    origin=origin, reply={"ok": False, "error": error})

    def noted(self, command: str, payload, reply: dict, *, user: str | None = None, origin: str = "zenoh") -> None:
        """A command answered without ``apply`` (a SCADA slot's acknowledge with nothing standing
        in it): audited as every other."""
        self._audit(t=self.c.clock.now(), user=user, command=command, payload=payload, origin=origin, reply=reply)

    def _audit(self, *, t, user, command, payload, origin, reply) -> None:
        """Queue the row; the queue is written in one transaction just after this loop turn (the
        reply goes first). One fsync for all the commands of a turn: a flood of queries costs the
        loop a commit per turn, not per query, and nothing waits for one on the e-stop's way."""
        ok = reply.get("ok") is True
        extra = {k: v for k, v in reply.items() if k not in ("ok", "error")}
        self._rows.append(dict(
            t=t, user=printable(user, OPERATOR_MAX) if user is not None else None,
            operator=claimed(payload), command=command,
            payload=received_text(payload),
            origin=printable(origin, AUDIT_TEXT_MAX), ok=ok,
            result="ok" if ok and "error" not in reply else printable(reply.get("error", ""), AUDIT_TEXT_MAX),
            reply=payload_text(extra) if extra else None))
        if len(self._rows) == 1:
            try:
                asyncio.get_running_loop().call_soon(self.flush_audit)
            except RuntimeError:      # no loop (a tool calling in): now
                self.flush_audit()

    def flush_audit(self) -> None:
        rows, self._rows = self._rows, []
        if not rows:
            return
        try:
            self.c.store.add_audits(rows)
        except LedgerUnwritable:
            # kept, oldest first, for the next flush (the ledger alarm's watch calls it); a flood
            # while the disk is full keeps its first rows and counts what it drops
            held = rows + self._rows
            if len(held) > AUDIT_HELD_MAX:
                log.error("audit: %d command(s) dropped, the ledger unwritable", len(held) - AUDIT_HELD_MAX)
            self._rows = held[:AUDIT_HELD_MAX]
        except Exception:   # an audit that cannot be written is loud, and never undoes the command
            log.exception("audit of %d command(s) not written: %s", len(rows),
                          ", ".join(sorted({r["command"] for r in rows})))

    # ------------------------------------------------------------ commands

    async def estop(self, payload, by: str | None = None) -> dict:
        """Any payload stops: fields of the wrong type are ignored, never a refusal. The reply
        comes once both devices confirmed their latches (``confirmed`` false: not within 2 s)."""
        name, why = None, None
        if isinstance(payload, dict):
            name, why = payload.get("operator"), payload.get("reason")
        name = by if by else (name if isinstance(name, str) else "unknown")
        why = why if isinstance(why, str) else ""
        reason = f"operator {name[:100]}" + (f": {why[:200]}" if why else "")
        self.c.trip_estop(reason)        # tripped already by whoever called; safe again, never waits
        log.warning("e-stop by %s: %s", name[:100], why[:200])   # the log filter escapes them
        try:
            confirmed = await self.c.emergency_stop(reason)
        except Exception:   # the latches were set already: say so, not "refused"
            log.exception("e-stop bookkeeping failed")
            confirmed = False
        return {"ok": True, "confirmed": bool(confirmed)}

    async def reset(self, payload, by: str | None = None) -> dict:
        """The feeder's reset, and the cleaner's when it is in ``estop`` (its thrusters' latch is
        released and confirmed before it leaves ``estop``). Refused while the e-stop it would
        release is still being confirmed (a reset 5 ms after an e-stop released stops no device had
        shown: the thrusters never stopped); one reset at a time (a second one, while the first
        waited for the thrusters, was refused for a latch the first had released)."""
        cmd, robot = parse(Bare, payload), self._robot()
        lane = getattr(self.c, "lane", None)
        if robot.state == "estop" and lane is not None and lane.confirming(CONFIRM_WAIT_S):
            raise Refused(f"reset: the e-stop is not confirmed by every device yet; reset once it is "
                          f"(within {CONFIRM_WAIT_S:g} s, or the estop alarm names the device)")
        async with self._resetting:
            log.warning("reset by %s: %s", by or cmd.operator, cmd.reason)
            feeder = robot.operator_reset()
            cleaner = getattr(self.c, "cleaner", None)
            if cleaner is None or cleaner.state != "estop":
                if feeder is not None and feeder.startswith("nothing to reset") and cleaner is not None:
                    feeder += f" (the cleaner is {cleaner.state})"
                return self._result(feeder)
            error = await cleaner.operator_reset()
            if error is not None:
                return {"ok": False, "error": error}
            return {"ok": True} if feeder is None or feeder.startswith("nothing to reset") else self._result(feeder)

    async def cleaner_start(self, payload, by: str | None = None) -> dict:
        """Start cleaning (resuming the saved map and path, or a fresh run once the last finished)."""
        return await self._cleaner("start", payload, by)

    async def cleaner_stop(self, payload, by: str | None = None) -> dict:
        """Stop where it is (``manual``): nothing of ours moves until a start or a return."""
        return await self._cleaner("stop", payload, by)

    async def cleaner_return(self, payload, by: str | None = None) -> dict:
        """Go to the dock (after re-acquiring the float, when it is not tracked)."""
        return await self._cleaner("go_home", payload, by)

    async def _cleaner(self, action: str, payload, by: str | None) -> dict:
        cmd = parse(Bare, payload)
        cleaner = getattr(self.c, "cleaner", None)
        if cleaner is None:
            raise Refused(f"command: {STARTING}" if self.c.cfg.cleaning is not None else f"command: {NO_CLEANER}")
        log.warning("cleaner %s by %s: %s", action, by or cmd.operator, cmd.reason)
        return self._result(await getattr(cleaner, action)())

    async def manual(self, payload, by: str | None = None) -> dict:
        cmd, robot = parse(Manual, payload), self._robot()
        log.warning("manual=%s by %s: %s", cmd.on, by or cmd.operator, cmd.reason)
        asked, busy = robot.manual_asked, robot.state
        reply = self._result(robot.set_manual(cmd.on))
        if reply.get("ok") and robot.manual_asked:
            reply["note"] = f"manual once the robot's current job ends (it is {busy})"
        elif reply.get("ok") and asked and not cmd.on:
            reply["note"] = "the manual control asked for is withdrawn"
        elif reply.get("ok") and not cmd.on and busy != "manual":
            reply["note"] = f"nothing to release: the robot is not in manual (it is {busy})"
        return reply

    async def feed(self, payload, by: str | None = None) -> dict:
        cmd = parse(Feed, payload, {"feeding": self.c.cfg.feeding})
        self._tank(cmd.tank)
        self._holds_fish(cmd.tank)                # food into an emptied tank: wasted, and counted as fed
        if cmd.tank in self.c.store.paused_tanks():
            raise Refused(f"tank: {cmd.tank} is paused (resume it first)")
        robot = self._robot()
        if robot.state in ("estop", "manual"):
            raise Refused(f"feeder is in {robot.state}")
        if cmd.tank in robot.pending:
            raise Refused(f"tank {cmd.tank} already has a demand waiting: it is being served")
        grams = robot.dispensing.portion(cmd.tank, cmd.grams)
        if grams <= 0:
            raise Refused(f"tank {cmd.tank} has had its ration today")
        now = self.c.clock.now()
        # in the ledger before it is accepted: a stop before it is served loses nothing (the restart
        # serves it, as the fish's demands), and the same request id sent again is truly done once
        demand_id = self.c.store.add_demand(cmd.tank, now, 0.0, source="operator", grams=grams)
        log.warning("feed %s %.0f g by %s: %s", cmd.tank, grams, by or cmd.operator, cmd.reason)
        robot.on_demand(Job(cmd.tank, now, demand_id, "operator", grams))
        return {"ok": True, "grams": round(grams, 1), "demand": demand_id}

    def _feed_as_it_stands(self, reply: dict) -> dict:
        """A feed's remembered reply sent again, unless an e-stop withdrew that feed since: "ok" of it
        told a client retrying after a lost reply that 50 g would go in, when none would."""
        demand = reply.get("demand")
        if demand is None or self.c.store.demand_outcome(demand) != "estop":
            return reply
        return {"ok": False, "withdrawn": True, "demand": demand,
                "error": "request: that feed was withdrawn by an e-stop before its portion started; "
                         "ask again after the reset, under a new request id"}

    async def ration(self, payload, by: str | None = None) -> dict:
        cmd = parse(SetRation, payload)
        self._tank(cmd.tank)
        if cmd.grams > 0:                         # (0 g stays possible: nothing to feed is what it says)
            self._holds_fish(cmd.tank)
        log.warning("ration %s = %.0f g by %s: %s", cmd.tank, cmd.grams, by or cmd.operator, cmd.reason)
        self.c.rations.set(cmd.tank, self.c.clock.now(), cmd.grams, "operator")
        self.c.publish_ration(cmd.tank)
        return {"ok": True}

    async def settle(self, payload, by: str | None = None) -> dict:
        cmd = parse(Settle, payload)
        if cmd.grams == 0 and not cmd.reason.strip():
            raise Refused("reason: settling a feed with grams=0 (none went in) needs a reason")
        robot = self._robot()
        try:
            feed = robot.dispensing.settle_suspect(cmd.id, cmd.grams, by or cmd.operator, cmd.reason)
        except LookupError:
            raise Refused(f"id: feed {cmd.id!r} is not suspect") from None
        return {"ok": True, "phase": feed.phase}

    async def ack(self, payload, by: str | None = None) -> dict:
        cmd = parse(Ack, payload)
        if cmd.all and (cmd.source is not None or cmd.kind is not None):
            raise Refused(f"{'source' if cmd.source is not None else 'kind'}: not with \"all\": true")
        if not cmd.all and cmd.source is None:
            raise Refused("source: required (or \"all\": true)")
        try:
            done = self.c.alarms.ack(who(by, cmd.operator), cmd.source, cmd.kind)
        except LookupError:
            field = "kind" if cmd.kind is not None and any(s == cmd.source for s, _ in self.c.alarms.known) \
                else "source"
            raise Refused(f"{field}: no such alarm") from None
        return {"ok": True, "acked": [{"source": a.source, "kind": a.kind} for a in done]}

    def _robot(self):
        if self.c.robot is None:
            raise Refused(STARTING)
        return self.c.robot

    def _tank(self, tank: str, field: str = "tank") -> None:
        if tank not in {t.id for t in self.c.cfg.tanks}:
            raise Refused(f"{field}: no tank {tank!r}")

    @staticmethod
    def _result(error: str | None) -> dict:
        return {"ok": True} if error is None else {"ok": False, "error": error}
