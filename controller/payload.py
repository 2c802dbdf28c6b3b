"""Bus payloads read strictly: JSON objects, UTF-8, no NaN/Infinity, no key given twice, no
nesting deeper than a payload of ours can need. Every fault is a ValueError saying what is wrong
(and, for a doubled key, which key), never a RecursionError on a Zenoh thread."""
from __future__ import annotations

import dataclasses
import itertools
import json
import re

from controller.text import printable

MAX_DEPTH = 32
"""Deepest nesting a payload may have: ours go four levels deep at most; Python's parser recurses."""
_STRINGS = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"')
_NOT_BRACKETS = re.compile(r"[^\[\]{}]+")
_STEP = {"[": 1, "{": 1, "]": -1, "}": -1}


@dataclasses.dataclass(frozen=True)
class Received:
    """A payload that was readable JSON but no object (["T3"], "T3", null, 42), as sent: refused
    (estop: ignored), and kept by the audit. Boxed, as None stands for no payload at all."""
    value: object


class Unread(dict):
    """The ``{}`` handed on for a payload that was empty, or that a lenient handler (estop) took
    though it was no object: ``received`` says what came for the audit, a Received, or None when
    nothing readable did (the audit kept ``{}``, a payload nobody sent)."""

    def __init__(self, received: Received | None = None):
        super().__init__()
        self.received = received


class NotAnObject(ValueError):
    """Readable JSON that is not an object; ``received`` keeps it for the audit."""

    def __init__(self, value):
        super().__init__(f"payload must be a JSON object, got {json_kind(value)}")
        self.received = Received(value)


def parse_object(raw: bytes) -> dict:
    """A payload as a dict; an empty one is ``{}`` (an ``Unread``). Raises ValueError saying what
    is wrong: not UTF-8, not JSON, not an object (``NotAnObject``), nested deeper than MAX_DEPTH,
    or a key given twice (``"grams: duplicate key"``: JSON parsers disagree on which one wins, so
    neither does)."""
    if not raw.strip():
        return Unread()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError("payload is not UTF-8") from None
    _check_depth(text)
    try:
        value = json.loads(text, parse_constant=_no_constant, object_pairs_hook=_unique_keys)
    except json.JSONDecodeError as exc:
        if exc.doc in _CONSTANTS:        # raised where the constant's place is not known: found here
            exc = json.JSONDecodeError(exc.msg, text, _constant_at(text))
        raise ValueError(f"payload is not JSON: {exc}") from None
    except RecursionError:  # _check_depth should have caught it; never let it reach a Zenoh thread
        raise ValueError(f"payload: nested deeper than {MAX_DEPTH} levels") from None
    except _DuplicateKey as exc:
        raise ValueError(str(exc)) from None
    except ValueError as exc:  # e.g. an integer of more than 4,300 digits
        raise ValueError(f"payload is not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise NotAnObject(value)
    return value


def json_kind(value) -> str:
    """What a decoded JSON value is, in JSON's words (not Python's NoneType, list, str)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    return {dict: "an object", list: "an array", str: "a string", int: "a number", float: "a number"}.get(
        type(value), type(value).__name__)


class _DuplicateKey(ValueError):
    pass


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    value = dict(pairs)
    if len(value) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise _DuplicateKey(f"{printable(key, 64)}: duplicate key")
            seen.add(key)
    return value


def _check_depth(text: str) -> None:
    """Refuse deep nesting before parsing: the parser recurses once per level, and a
    RecursionError is no ValueError. Strings are cut out first (brackets in them do not count);
    both passes are regular expressions, so a megabyte costs milliseconds, not a Python loop."""
    if text.count("[") + text.count("{") <= MAX_DEPTH:
        return
    brackets = _NOT_BRACKETS.sub("", _STRINGS.sub("", text))
    if max(itertools.accumulate(map(_STEP.__getitem__, brackets)), default=0) > MAX_DEPTH:
        raise ValueError(f"payload: nested deeper than {MAX_DEPTH} levels")


_CONSTANTS = ("NaN", "Infinity", "-Infinity")
_TOKENS = re.compile(r'"(?:\\.|[^"\\])*"|(NaN|-?Infinity)')


def _no_constant(name: str):
    raise json.JSONDecodeError(f"{name} is not JSON", name, 0)


def _constant_at(text: str) -> int:
    """Where the first NaN or Infinity outside a string is (0 if none is)."""
    return next((m.start(1) for m in _TOKENS.finditer(text) if m.group(1)), 0)
