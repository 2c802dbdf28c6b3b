"""Operator overrides over Zenoh: ``farm/{site}/override/{command}`` queryables.

Every payload may carry ``operator`` and ``reason``; each command validates its own fields.
``estop`` is never refused: any payload, even an empty or unreadable one, stops the robot.
"""
from __future__ import annotations

import logging

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from controller.feeding.robot import Job

log = logging.getLogger("fishfarm.override")


STARTING = {"ok": False, "error": "the controller is starting: waiting for its devices"}


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
        bus.overrides({name: getattr(self, name) for name in ("estop", "reset", "manual", "feed", "ration")},
                      lenient=("estop",))
        bus.queryable("status", self.status, lenient=True)

    async def status(self, payload) -> dict:
        return self.c.status()

    async def estop(self, payload) -> dict:
        who = payload.get("operator", "unknown") if isinstance(payload, dict) else "unknown"
        why = payload.get("reason", "") if isinstance(payload, dict) else ""
        log.warning("e-stop by %s: %s", who, why)
        await self.c.emergency_stop(f"operator {who}" + (f": {why}" if why else ""))
        return {"ok": True}

    async def reset(self, payload) -> dict:
        cmd = self._parse(_Command, payload)
        if isinstance(cmd, dict):
            return cmd
        if self.c.robot is None:
            return STARTING
        log.warning("reset by %s: %s", cmd.operator, cmd.reason)
        return self._result(self.c.robot.operator_reset())

    async def manual(self, payload) -> dict:
        cmd = self._parse(Manual, payload)
        if isinstance(cmd, dict):
            return cmd
        if self.c.robot is None:
            return STARTING
        log.warning("manual=%s by %s: %s", cmd.on, cmd.operator, cmd.reason)
        return self._result(self.c.robot.set_manual(cmd.on))

    async def feed(self, payload) -> dict:
        cmd = self._parse(Feed, payload)
        if isinstance(cmd, dict):
            return cmd
        if cmd.tank not in self.c.sensor_tank.values():
            return {"ok": False, "error": f"tank: no tank {cmd.tank!r}"}
        if self.c.robot is None:
            return STARTING
        robot = self.c.robot
        if robot.state in ("estop", "manual"):
            return {"ok": False, "error": f"feeder is in {robot.state}"}
        if cmd.tank in robot.pending:
            return {"ok": False, "error": f"tank {cmd.tank} already has a demand waiting: it is being served"}
        grams = robot.dispensing.portion(cmd.tank, cmd.grams)
        if grams <= 0:
            return {"ok": False, "error": f"tank {cmd.tank} has had its ration today"}
        log.warning("feed %s %.0f g by %s: %s", cmd.tank, grams, cmd.operator, cmd.reason)
        robot.on_demand(Job(cmd.tank, self.c.clock.now(), None, "operator", grams))
        return {"ok": True, "grams": round(grams, 1)}

    async def ration(self, payload) -> dict:
        cmd = self._parse(SetRation, payload)
        if isinstance(cmd, dict):
            return cmd
        if cmd.tank not in self.c.sensor_tank.values():
            return {"ok": False, "error": f"tank: no tank {cmd.tank!r}"}
        log.warning("ration %s = %.0f g by %s: %s", cmd.tank, cmd.grams, cmd.operator, cmd.reason)
        self.c.rations.set(cmd.tank, self.c.clock.now(), cmd.grams, "operator")
        self.c.publish_ration(cmd.tank)
        return {"ok": True}

    @staticmethod
    def _parse(model, payload):
        try:
            return model.model_validate(payload if payload is not None else {})
        except ValidationError as exc:
            err = exc.errors()[0]
            field = ".".join(str(p) for p in err["loc"]) or "payload"
            return {"ok": False, "error": f"{field}: {err['msg']}"}

    @staticmethod
    def _result(error: str | None) -> dict:
        return {"ok": True} if error is None else {"ok": False, "error": error}
