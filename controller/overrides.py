"""Operator overrides over Zenoh: ``farm/{site}/override/{command}`` queryables.

Every payload may carry ``operator`` and ``reason``; each command validates its own fields.
``estop`` is never refused: any payload, even an empty or unreadable one, stops the robot.
"""
from __future__ import annotations

import logging

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from controller.feeding.robot import Job

log = logging.getLogger("fishfarm.override")


STARTING = "the controller is starting: waiting for its devices"


class Refused(Exception):
    """A command the controller will not carry out; its text is the reply's error."""


def _parse(model, payload):
    try:
        return model.model_validate(payload if payload is not None else {})
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(p) for p in err["loc"]) or "payload"
        raise Refused(f"{field}: {err['msg']}") from None


def _answering(handler):
    """A refusal becomes ``{"ok": false, "error": ...}``; everything else is the bus's business."""
    async def answer(payload) -> dict:
        try:
            return await handler(payload)
        except Refused as exc:
            return {"ok": False, "error": str(exc)}
    return answer


class _Command(BaseModel):
    model_config = ConfigDict(extra="forbid")
    operator: str = "unknown"
    reason: str = ""


class Manual(_Command):
    on: bool = True


class Feed(_Command):
    tank: str
    grams: float = Field(gt=0, le=5000)


class SetRation(_Command):
    tank: str
    grams: float = Field(ge=0, le=1_000_000)


class Overrides:
    def __init__(self, controller):
        self.c = controller

    def declare(self, bus) -> None:
        # one queryable on override/*: an unknown command is refused with a reason, not left unanswered
        commands = ("estop", "reset", "manual", "feed", "ration")
        # estop also trips the latches on the Zenoh thread itself, before the payload is parsed
        bus.overrides({name: _answering(getattr(self, name)) for name in commands}, lenient=("estop",),
                      urgent={"estop": lambda: self.c.trip_estop("operator e-stop")})
        bus.queryable("status", self.status, lenient=True)

    async def status(self, payload) -> dict:
        return self.c.status()

    async def estop(self, payload) -> dict:
        """Any payload stops: fields of the wrong type are ignored, never a refusal. The reply
        comes once both devices confirmed their latches (``confirmed`` false: not within 2 s)."""
        who = why = None
        if isinstance(payload, dict):
            who, why = payload.get("operator"), payload.get("reason")
        who = who if isinstance(who, str) else "unknown"
        why = why if isinstance(why, str) else ""
        log.warning("e-stop by %r: %r", who[:100], why[:200])
        try:
            confirmed = await self.c.emergency_stop(f"operator {who[:100]}" + (f": {why[:200]}" if why else ""))
        except Exception:   # the latches were set on the Zenoh thread already: say so, not "refused"
            log.exception("e-stop bookkeeping failed")
            confirmed = False
        return {"ok": True, "confirmed": bool(confirmed)}

    async def reset(self, payload) -> dict:
        cmd, robot = _parse(_Command, payload), self._robot()
        log.warning("reset by %s: %s", cmd.operator, cmd.reason)
        return self._result(robot.operator_reset())

    async def manual(self, payload) -> dict:
        cmd, robot = _parse(Manual, payload), self._robot()
        log.warning("manual=%s by %s: %s", cmd.on, cmd.operator, cmd.reason)
        return self._result(robot.set_manual(cmd.on))

    async def feed(self, payload) -> dict:
        cmd = _parse(Feed, payload)
        self._tank(cmd.tank)
        robot = self._robot()
        if robot.state in ("estop", "manual"):
            raise Refused(f"feeder is in {robot.state}")
        if cmd.tank in robot.pending:
            raise Refused(f"tank {cmd.tank} already has a demand waiting: it is being served")
        grams = robot.dispensing.portion(cmd.tank, cmd.grams)
        if grams <= 0:
            raise Refused(f"tank {cmd.tank} has had its ration today")
        log.warning("feed %s %.0f g by %s: %s", cmd.tank, grams, cmd.operator, cmd.reason)
        robot.on_demand(Job(cmd.tank, self.c.clock.now(), None, "operator", grams))
        return {"ok": True, "grams": round(grams, 1)}

    async def ration(self, payload) -> dict:
        cmd = _parse(SetRation, payload)
        self._tank(cmd.tank)
        log.warning("ration %s = %.0f g by %s: %s", cmd.tank, cmd.grams, cmd.operator, cmd.reason)
        self.c.rations.set(cmd.tank, self.c.clock.now(), cmd.grams, "operator")
        self.c.publish_ration(cmd.tank)
        return {"ok": True}

    def _robot(self):
        if self.c.robot is None:
            raise Refused(STARTING)
        return self.c.robot

    def _tank(self, tank: str) -> None:
        if tank not in self.c.sensor_tank.values():
            raise Refused(f"tank: no tank {tank!r}")

    @staticmethod
    def _result(error: str | None) -> dict:
        return {"ok": True} if error is None else {"ok": False, "error": error}
