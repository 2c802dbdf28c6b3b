"""Modbus TCP framing held to the spec, before any request reaches the map: MBAP headers no frame
has (``broken_mbap``), and request PDUs decoded strictly (``StrictDecoder``): a function the map
does not serve answers 01, a request whose fields do not fit its length or its function's limits 03.
"""
from __future__ import annotations

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU

from controller.scada.register_map import COIL, DI, HR, IR

READ_KIND = {1: COIL, 2: DI, 3: HR, 4: IR, 23: HR}
WRITE_KIND = {5: COIL, 15: COIL, 6: HR, 16: HR, 23: HR}
# the functions the map answers: reads, writes, and the device's identification (43). pymodbus's
# others (diagnostics, event counters, file records, FIFO queues) would answer from its own
# counters or invented data; a SCADA asking for them gets exception 01
SERVED = frozenset({*READ_KIND, *WRITE_KIND, 43})


def broken_mbap(buf: bytes) -> bool:
    """A header no Modbus TCP frame has: protocol id not 0, or a length outside 2..254 (unit id +
    a PDU of at most 253 bytes). pymodbus would wait for the rest of such a frame for ever."""
    if len(buf) < 6:
        return False
    length = int.from_bytes(buf[4:6], "big")
    return buf[2:4] != b"\x00\x00" or not 2 <= length <= 254


class _Refused(ModbusPDU):
    """A request answered with an exception before any store sees it: its own function code + 0x80
    (pymodbus answers what it cannot decode with a bare 0x80, which no client can match)."""

    def __init__(self, function_code: int, code: ExcCodes):
        super().__init__()
        self.function_code, self.code = function_code, code

    async def datastore_update(self, context, device_id: int) -> ModbusPDU:
        if device_id not in context.device_ids():
            raise NoSuchIdException(f"unit {device_id}")       # 0B first, as for any request
        return ExceptionResponse(self.function_code, self.code)


# the PDU length of each served function but 43: fixed, or fixed + the byte count at an offset.
# pymodbus decodes the fields it wants and ignores what follows, so a frame with bytes the MBAP
# length counts beyond its request (a client's framing bug, two requests run together) was acted on
_FIXED = {1: 5, 2: 5, 3: 5, 4: 5, 5: 5, 6: 5}
_COUNTED = {15: (6, 5), 16: (6, 5), 23: (10, 9)}     # fc: (length before the data, byte count's offset)


def _whole(frame: bytes) -> bool:
    """Whether a request PDU is exactly as long as its own fields say (43: pymodbus checks it)."""
    fc = frame[0]
    if fc in _FIXED:
        return len(frame) == _FIXED[fc]
    if fc in _COUNTED:
        head, at = _COUNTED[fc]
        return len(frame) > at and len(frame) == head + frame[at]
    return True


class StrictDecoder(DecodePDU):
    """pymodbus's request decoder, held to the Modbus spec: FC 5 takes only 0xFF00 (on) or 0x0000
    (off) — pymodbus reads any other value as on, so 0x0001 to the reset coil released the e-stop —
    else exception 03; a request of a known function that does not decode (a quantity of 0 or over
    the function's limit, a byte count that does not match), or is longer or shorter than its
    fields say, 03; an unknown function 01."""

    def __init__(self):
        super().__init__(True)

    def decode(self, frame: bytes) -> ModbusPDU | None:
        if not frame:
            return None
        fc = frame[0]
        if fc not in SERVED:
            return _Refused(fc & 0x7F, ExcCodes.ILLEGAL_FUNCTION)
        if fc == 5 and len(frame) >= 5 and frame[3:5] not in (b"\xff\x00", b"\x00\x00"):
            return _Refused(fc, ExcCodes.ILLEGAL_VALUE)
        if not _whole(frame):
            return _Refused(fc, ExcCodes.ILLEGAL_VALUE)
        pdu = super().decode(frame)
        if pdu is None:
            return _Refused(fc, ExcCodes.ILLEGAL_VALUE if fc in self.pdu_table else ExcCodes.ILLEGAL_FUNCTION)
        return pdu


__all__ = ["READ_KIND", "SERVED", "WRITE_KIND", "StrictDecoder", "broken_mbap"]
