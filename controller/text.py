"""Text from outside (operators, payloads, devices) made safe for the log, the ledger and replies.

A newline, a carriage return or an escape sequence in an operator's reason could forge a log line
or repaint a terminal; a megabyte of it would travel in every ``status``. What reaches the log,
the store or a reply is escaped and bounded here.
"""
from __future__ import annotations

import re

# C0 and C1 controls, DEL, Unicode line/paragraph separators, the bidirectional overrides and
# marks (text that displays in another order than it reads), the invisible ones (an operator
# "bob\u2063\u00ad" shows as "bob"): every format character (Unicode category Cf: zero-width
# space and joiners, word joiner, BOM, soft hyphen, invisible operators, the tag block, Egyptian and
# musical format controls), every default-ignorable code point (variation selectors, the Hangul
# and Mongolian fillers, combining grapheme joiner) and the braille blank; and lone surrogates
# (JSON's "\ud800": no UTF-8). tests/controller/test_text.py checks the Cf list against Python's
# own Unicode tables.
CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u00ad\u034f\u0600-\u0605\u061c\u06dd\u070f\u0890\u0891\u08e2"
                     "\u115f\u1160\u17b4\u17b5\u180b-\u180f\u200b-\u200f\u2028-\u202e\u2060-\u206f"
                     "\u2800\u3164\ufe00-\ufe0f\ufeff\uffa0\ufff0-\ufffb\ud800-\udfff"
                     "\U000110bd\U000110cd\U00013430-\U0001343f\U0001bca0-\U0001bca3"
                     "\U0001d173-\U0001d17a\U000e0000-\U000e0fff]")
ELLIPSIS = "…"


_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(match: re.Match) -> str:
    char = match.group()
    if char in _NAMED:
        return _NAMED[char]
    code = ord(char)
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def printable(text: object, limit: int) -> str:
    """``text`` on one line of at most ``limit`` characters: controls escaped (``\\n``, ``\\x1b``),
    the tail cut with an ellipsis. Anything not a string is shown by its ``repr``, bounded."""
    if not isinstance(text, str):
        text = _short_repr(text, limit)
    if len(text) > 4 * limit:          # escaping at most quadruples a character: cut before the work
        text = text[:4 * limit]
    text = CONTROL.sub(_escape, text)
    return text if len(text) <= limit else text[:max(limit - 1, 0)] + ELLIPSIS


def _short_repr(value: object, limit: int) -> str:
    try:
        text = repr(value)
    except Exception:  # a hostile __repr__ is no reason to lose the message
        text = f"<{type(value).__name__}>"
    return text[:4 * limit]


def has_control(text: str) -> bool:
    return CONTROL.search(text) is not None
