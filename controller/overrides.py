"""Operator overrides over Zenoh: ``farm/{site}/override/{command}`` queryables.

Every payload may carry ``operator`` and ``reason``; each command validates its own fields
strictly: a field of the wrong JSON type (``grams=true``, ``grams="40"``, ``on="yes"``), a number
that is not finite or out of range, an unknown field, a key given twice (refused by the bus's
decoder) or text too long or holding control characters is refused with
``{"ok": false, "error": "<field>: <why>"}`` and nothing is done. Nothing is coerced.
``estop`` is never refused: any payload, even an empty or unreadable one, stops the robot.
"""
from __future__ import annotations

import logging
from typing import Annotated

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator

from controller.feeding.robot import Job
from controller.text import has_control, printable

log = logging.getLogger("fishfarm.override")

STARTING = "the controller is starting: waiting for its devices"
OPERATOR_MAX = 64
REASON_MAX = 200
RATION_MAX_G = 1_000_000.0     # a tonne a day for one tank: beyond that it is a typing error
LOG_LINE_MAX = 1000


class _OneLine(logging.Filter):
    """Every line this module logs is one bounded line, whatever an operator's payload held (the
    e-stop logs what it was given, unvalidated)."""

    def filter(self, record: logging.LogRecord) -> bool:
        record.msg, record.args = printable(record.getMessage(), LOG_LINE_MAX), None
        return True


log.addFilter(_OneLine())


class Refused(Exception):
    """A command the controller will not carry out; its text is the reply's error."""


def _one_line(text: str) -> str:
    if has_control(text):
        raise ValueError("control characters (newline, carriage return, escape...) are not allowed")
    return text


Operator = Annotated[str, Field(min_length=1, max_length=OPERATOR_MAX), AfterValidator(_one_line)]
Reason = Annotated[str, Field(max_length=REASON_MAX), AfterValidator(_one_line)]
TankId = Annotated[str, Field(pattern=r"^[A-Za-z0-9_-]{1,32}$")]   # as farm.toml's tank ids

_JSON_TYPE = {bool: "a boolean", str: "a string", dict: "an object", list: "an array", type(None): "null",
              int: "a number", float: "a number"}
_WANTED = {"float_type": "a number", "int_type": "an integer", "bool_type": "true or false",
           "string_type": "a string"}


def _why(err: dict) -> str:
    """Pydantic's error as an operator reads it: what the field must be, never the value sent."""
    kind, ctx = err["type"], err.get("ctx") or {}
    if kind == "extra_forbidden":
        return "unknown field"
    if kind == "missing":
        return "required"
    if kind in _WANTED:
        given = err.get("input")
        if isinstance(given, int) and not isinstance(given, bool) and kind == "float_type":
            return "out of range"                      # an integer too large for a float
        return f"must be {_WANTED[kind]}, not {_JSON_TYPE.get(type(given), type(given).__name__)}"
    if kind == "finite_number":
        return "must be a finite number"
    bound = {"greater_than_equal": ("at least", "ge"), "greater_than": ("more than", "gt"),
             "less_than_equal": ("at most", "le"), "less_than": ("less than", "lt")}.get(kind)
    if bound is not None:
        return f"must be {bound[0]} {ctx.get(bound[1]):g}"
    if kind == "string_too_long":
        return f"longer than {ctx.get('max_length')} characters"
    if kind == "string_too_short":
        return "must not be empty"
    if kind == "string_pattern_mismatch":
        return "letters, digits, _ and - only (1 to 32)"
    msg = err["msg"]
    return msg[len("Value error, "):] if msg.startswith("Value error, ") else msg


def _parse(model, payload, context: dict | None = None):
    try:
        return model.model_validate(payload if payload is not None else {}, context=context)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = printable(".".join(str(p) for p in err["loc"]) or "payload", 64)
        raise Refused(f"{field}: {_why(err)}") from None


def _answering(handler):
    """A refusal becomes ``{"ok": false, "error": ...}``; everything else is the bus's business."""
    async def answer(payload) -> dict:
        try:
            return await handler(payload)
        except Refused as exc:
            return {"ok": False, "error": str(exc)}
    return answer


class _Command(BaseModel):
    # strict: JSON's true is no number and "40" no grams; ints are taken for floats (40 is 40.0)
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)
    operator: Operator = "unknown"
    reason: Reason = ""


class Manual(_Command):
    on: bool = True


class Feed(_Command):
    tank: TankId
    grams: float

    @field_validator("grams")
    @classmethod
    def _one_portion(cls, grams: float, info: ValidationInfo) -> float:
        """Between the smallest portion served and one portion: an ask outside is a mistake to
        say, not a number to quietly clamp (1e-300 g would be a 1 ms auger run)."""
        feeding = info.context["feeding"]
        if grams < feeding.min_portion_g:
            raise ValueError(f"less than feeding.min_portion_g ({feeding.min_portion_g:g} g)")
        if grams > feeding.portion_g:
            raise ValueError(f"more than one portion, feeding.portion_g ({feeding.portion_g:g} g)")
        return grams


class SetRation(_Command):
    tank: TankId
    # -0.0 is within 0.. and would be a ration of "-0 g" in the log, the ledger and the topic
    grams: Annotated[float, Field(ge=0, le=RATION_MAX_G), AfterValidator(lambda g: g + 0.0)]


class Settle(_Command):
    """An operator's word on a suspect feed: the grams that went in (0 with a reason: none)."""
    id: str = Field(min_length=1, max_length=64)
    grams: float = Field(ge=0, le=5000)


class Overrides:
    def __init__(self, controller):
        self.c = controller

    def declare(self, bus) -> None:
        # one queryable on override/*: an unknown command is refused with a reason, not left unanswered
        commands = ("estop", "reset", "manual", "feed", "ration", "settle")
        # estop also trips the latches on the Zenoh thread itself, before the payload is parsed
        bus.overrides({name: _answering(getattr(self, name)) for name in commands}, lenient=("estop",),
                      urgent={"estop": lambda: self.c.trip_estop("operator e-stop")})
        bus.queryable("status", self.status, lenient=True)

    async def apply(self, command: str, payload: object, *, user: str | None = None,
                    origin: str = "zenoh") -> dict:
        """Every override, from Zenoh or Modbus (PLAN8's one entry). Minimal dispatcher until the
        audit branch's lands: maps the command to its handler; never raises for bad input."""
        handlers = {"estop": self.estop, "reset": self.reset, "manual": self.manual, "feed": self.feed,
                    "ration": self.ration, "settle": self.settle}
        handler = handlers.get(command)
        if handler is None:
            return {"ok": False, "error": f"command: not available yet: {printable(str(command), 40)}"}
        log.info("override %s from %s (%s)", command, origin, user or "unauthenticated")
        return await _answering(handler)(payload)

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
        log.warning("e-stop by %s: %s", who[:100], why[:200])   # the log filter escapes them
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
        cmd = _parse(Feed, payload, {"feeding": self.c.cfg.feeding})
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

    async def settle(self, payload) -> dict:
        cmd = _parse(Settle, payload)
        if cmd.grams == 0 and not cmd.reason.strip():
            raise Refused("reason: settling a feed with grams=0 (none went in) needs a reason")
        robot = self._robot()
        try:
            feed = robot.dispensing.settle_suspect(cmd.id, cmd.grams, cmd.operator, cmd.reason)
        except LookupError:
            raise Refused(f"id: feed {cmd.id!r} is not suspect") from None
        return {"ok": True, "phase": feed.phase}

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
