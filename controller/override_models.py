"""What each override's payload may hold, strictly (pydantic, nothing coerced), and how a refusal
reads: ``"<field>: <why>"``, naming the field and never echoing the value sent.

Every payload may carry ``operator`` (the name the sender claims) and ``reason``. A field of the
wrong JSON type (``grams=true``, ``grams="40"``, ``count=2.0``), a number that is not finite or out
of range, an unknown field, text too long or holding control characters is refused.
"""
from __future__ import annotations

import json
from typing import Annotated

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator

from controller.payload import Received, Unread
from controller.text import has_control, printable

STARTING = "the controller is starting: waiting for its devices"
OPERATOR_MAX = 64
REASON_MAX = 200
RATION_MAX_G = 1_000_000.0     # a tonne a day for one tank: beyond that it is a typing error
COUNT_MAX = 10_000_000         # fish in one event: beyond the largest sea cage, a typing error
SOURCE_MAX = 100
AUDIT_PAYLOAD_MAX = 1000       # characters of a payload kept in the audit
AUDIT_TEXT_MAX = 300           # characters of any other audit field


class Refused(Exception):
    """A command the controller will not carry out; its text is the reply's error."""


def _one_line(text: str) -> str:
    if has_control(text):
        raise ValueError("control characters (newline, carriage return, escape...) are not allowed")
    return text


Operator = Annotated[str, Field(min_length=1, max_length=OPERATOR_MAX), AfterValidator(_one_line)]
Reason = Annotated[str, Field(max_length=REASON_MAX), AfterValidator(_one_line)]
TankId = Annotated[str, Field(pattern=r"^[A-Za-z0-9_-]{1,32}$")]   # as farm.toml's tank ids
AlarmName = Annotated[str, Field(min_length=1, max_length=SOURCE_MAX), AfterValidator(_one_line)]
FishCount = Annotated[int, Field(gt=0, le=COUNT_MAX)]
REQUEST_PATTERN = r"^[!-~]{1,64}$"       # printable ASCII, no space: a UUID fits
RequestId = Annotated[str, Field(pattern=REQUEST_PATTERN)]
_PATTERNS = {r"^[A-Za-z0-9_-]{1,32}$": "letters, digits, _ and - only (1 to 32)",
             REQUEST_PATTERN: "printable ASCII without spaces only (1 to 64)"}

_JSON_TYPE = {bool: "a boolean", str: "a string", dict: "an object", list: "an array", type(None): "null",
              int: "a number", float: "a number"}
_WANTED = {"float_type": "a number", "int_type": "an integer", "bool_type": "true or false",
           "string_type": "a string"}


def _bound(value) -> str:
    return f"{value}" if isinstance(value, int) else f"{value:g}"


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
        return f"must be {bound[0]} {_bound(ctx.get(bound[1]))}"
    if kind == "string_too_long":
        return f"longer than {ctx.get('max_length')} characters"
    if kind == "string_too_short":
        return "must not be empty"
    if kind == "string_pattern_mismatch":
        return _PATTERNS.get(ctx.get("pattern"), "not of the form asked")
    msg = err["msg"]
    return msg[len("Value error, "):] if msg.startswith("Value error, ") else msg


def parse(model, payload, context: dict | None = None):
    try:
        return model.model_validate(payload if payload is not None else {}, context=context)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = printable(".".join(str(p) for p in err["loc"]) or "payload", 64)
        raise Refused(f"{field}: {_why(err)}") from None


class Command(BaseModel):
    # strict: JSON's true is no number and "40" no grams; ints are taken for floats (40 is 40.0)
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)
    operator: Operator = "unknown"
    reason: Reason = ""
    request: RequestId | None = None     # controller.override_requests: sent again, done once


class Manual(Command):
    on: bool = True


class Feed(Command):
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


class SetRation(Command):
    tank: TankId
    # -0.0 is within 0.. and would be a ration of "-0 g" in the log, the ledger and the topic
    grams: Annotated[float, Field(ge=0, le=RATION_MAX_G), AfterValidator(lambda g: g + 0.0)]


class Settle(Command):
    """An operator's word on a suspect feed: the grams that went in (0 with a reason: none)."""
    # one line, as every text an operator sends (a storm's id with a newline reached the handler)
    id: Annotated[str, Field(min_length=1, max_length=64), AfterValidator(_one_line)]
    grams: float = Field(ge=0, le=5000)


class Tank(Command):
    """pause, resume, start-survey."""
    tank: TankId


class Ack(Command):
    """Acknowledge the alarms of ``source`` (one ``kind`` of it, or all), or ``"all": true``."""
    source: AlarmName | None = None
    kind: AlarmName | None = None
    all: bool = False


class Loss(Command):
    """mortality, harvest: fish that left the tank."""
    tank: TankId
    count: FishCount


class Transfer(Command):
    tank: TankId
    to: TankId
    count: FishCount


class Bare(Command):
    """Commands with nothing but operator and reason: reset, the cleaner stubs."""


# ---------------------------------------------------------------- the audit's copy of a payload

def _shrunk(value, depth: int = 0):
    """A copy bounded before it is written out: a 5 MB reason costs a slice, not a 5 MB dump."""
    if isinstance(value, str):
        return value if len(value) <= AUDIT_PAYLOAD_MAX else value[:AUDIT_PAYLOAD_MAX]
    if isinstance(value, bool) or value is None or isinstance(value, float):
        return value
    if isinstance(value, int):
        return value if value.bit_length() <= 256 else f"<integer of {value.bit_length()} bits>"
    if depth >= 4:
        return "…"
    if isinstance(value, dict):
        return {str(k)[:100]: _shrunk(v, depth + 1) for k, v in list(value.items())[:32]}
    if isinstance(value, list | tuple):
        return [_shrunk(v, depth + 1) for v in value[:32]]
    return printable(value, 100)


def payload_text(payload) -> str:
    """The payload as the audit keeps it: JSON, one line, escaped, at most AUDIT_PAYLOAD_MAX."""
    try:
        text = json.dumps(_shrunk(payload), ensure_ascii=False, separators=(",", ":"))
    except (TypeError, ValueError):
        text = printable(payload, AUDIT_PAYLOAD_MAX)
    return printable(text, AUDIT_PAYLOAD_MAX)


def received_text(payload) -> str | None:
    """The audit's payload: as received, or None when nothing readable came (an ``Unread``)."""
    if isinstance(payload, Unread):
        payload = payload.received
    if isinstance(payload, Received):
        return payload_text(payload.value)
    return None if payload is None else payload_text(payload)


def claimed(payload) -> str | None:
    """The operator name a payload claims (any string, escaped and bounded), or None."""
    who = payload.get("operator") if isinstance(payload, dict) else None
    return printable(who, OPERATOR_MAX) if isinstance(who, str) else None


def who(user: str | None, operator: str | None) -> str:
    """The name records carry: the authenticated user, else the claimed name, marked so."""
    return user if user else f"{operator or 'unknown'} (claimed)"
