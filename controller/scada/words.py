"""Values as Modbus words and back: each of the register map's data types (``WORDS`` words each),
scaled, saturated at the type's ends, with one marker per type for "no value"."""
from __future__ import annotations

import math
import struct

WORDS = {"bool": 1, "u16": 1, "i16": 1, "u32": 2, "i32": 2, "f32": 2}
NO_VALUE = {"u16": 0xFFFF, "i16": -0x8000, "u32": 0xFFFF_FFFF, "i32": -0x8000_0000, "f32": math.nan}
FLT_MAX = 3.4028234663852886e38


def encode(dtype: str, value, scale: float = 1.0, word_order: str = "big") -> list[int]:
    """A value as the words on the wire; None or NaN as "no value". A number beyond what the type
    holds reads as the type's end (saturated, as a PLC's analogue input does): "no value" is for
    what the controller does not know, and an FCR of 700 is known (it read 0xFFFF)."""
    if dtype == "bool":
        return [int(bool(value))]
    if dtype == "f32":
        x = math.nan if value is None else float(value) / scale
        if abs(x) > FLT_MAX:                            # struct cannot pack it; inf stays inf
            x = math.copysign(math.inf if math.isinf(x) else FLT_MAX, x)
        hi, lo = struct.unpack(">HH", struct.pack(">f", x))
        return [hi, lo] if word_order == "big" else [lo, hi]
    lo_lim, hi_lim = {"u16": (0, 0xFFFE), "i16": (-0x7FFF, 0x7FFF), "u32": (0, 0xFFFF_FFFE),
                      "i32": (-0x7FFF_FFFF, 0x7FFF_FFFF)}[dtype]
    if value is None or isinstance(value, float) and math.isnan(value):
        raw = NO_VALUE[dtype]
    elif isinstance(value, float) and math.isinf(value):
        raw = hi_lim if value > 0 else lo_lim
    else:
        raw = min(max(round(value / scale), lo_lim), hi_lim)
    if dtype in ("u16", "i16"):
        return [raw & 0xFFFF]
    raw &= 0xFFFF_FFFF
    hi, lo = raw >> 16, raw & 0xFFFF
    return [hi, lo] if word_order == "big" else [lo, hi]


def decode(dtype: str, words: list[int], scale: float = 1.0, word_order: str = "big"):
    """Words from the wire as a value (None for the "no value" marker)."""
    if dtype in ("bool", "u16", "i16"):
        raw = words[0] & 0xFFFF
        if dtype == "bool":
            return bool(raw)
        if dtype == "i16" and raw >= 0x8000:
            raw -= 0x10000
        return None if raw == NO_VALUE[dtype] else raw * scale
    hi, lo = (words[0], words[1]) if word_order == "big" else (words[1], words[0])
    if dtype == "f32":
        x = struct.unpack(">f", struct.pack(">HH", hi, lo))[0]
        return None if math.isnan(x) else x * scale
    raw = (hi << 16) | lo
    if dtype == "i32" and raw >= 0x8000_0000:
        raw -= 0x1_0000_0000
    return None if raw == NO_VALUE[dtype] else raw * scale
