"""The rail drive's CAN frames (the motor controller's protocol), as data. Standard 11-bit ids, a
node id (1..127), little-endian (as CANopen), distances in 0.1 mm, speeds in mm/s:

    0x200+node  command  controller -> drive   DLC 8: op u8, seq u8, target i32 (0.1 mm), speed u16 (mm/s)
    0x180+node  status   drive -> controller   DLC 8: position i24 (0.1 mm), velocity i16 (mm/s),
                                                      state|flags u8, fault u8, last accepted seq u8
    0x280+node  reply    drive -> controller   DLC 3: seq u8, op u8, result u8 (0 accepted, else reason)

Both ends use these: the driver (devices/rail/can_drive.py) and the simulated drive (devices/sim/rail.py).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

import can

COMMAND_BASE, STATUS_BASE, REPLY_BASE = 0x200, 0x180, 0x280
STATES = ("unhomed", "homing", "idle", "moving", "fault", "estop")   # state code = index
FLAG_HOMED, FLAG_AT_TARGET, FLAG_AT_LIMIT = 0x08, 0x10, 0x20          # high bits of the state byte
_DMM = 10_000.0       # 0.1 mm per metre
_MM = 1_000.0


class Op(IntEnum):
    HOME = 1
    MOVE = 2
    STOP = 3
    ESTOP = 4
    CLEAR_FAULT = 5


class Reason(IntEnum):
    """Result byte of a reply: why the drive refused a command."""

    ACCEPTED = 0
    NOT_HOMED = 1       # MOVE before HOME
    IN_ESTOP = 2        # latched until CLEAR_FAULT
    IN_FAULT = 3        # latched until CLEAR_FAULT
    OUT_OF_RANGE = 4    # MOVE target beyond the soft limits
    BUSY = 5            # MOVE while homing; CLEAR_FAULT while the carriage still rolls
    BAD_COMMAND = 6     # unknown op or wrong length


class Fault(IntEnum):
    NONE = 0
    STALL = 1           # carriage blocked: following error, the drive cut the current
    OVERCURRENT = 2
    OVERTEMP = 3
    ENCODER = 4


@dataclass(frozen=True, slots=True)
class Command:
    op: Op
    seq: int
    target_m: float = 0.0
    speed_m_s: float = 0.0      # 0: the drive's own maximum

    def to_message(self, node: int) -> can.Message:
        data = struct.pack("<BBiH", self.op, self.seq, round(self.target_m * _DMM),
                           round(self.speed_m_s * _MM))
        return can.Message(arbitration_id=COMMAND_BASE + node, is_extended_id=False, data=data)

    @classmethod
    def from_bytes(cls, data: bytes) -> Command:
        """Raises ValueError on a frame that is not a command (the drive answers BAD_COMMAND)."""
        if len(data) != 8:
            raise ValueError(f"command frame has {len(data)} bytes, not 8")
        op, seq, target, speed = struct.unpack("<BBiH", bytes(data))
        return cls(Op(op), seq, target / _DMM, speed / _MM)


@dataclass(frozen=True, slots=True)
class StatusFrame:
    position_m: float
    velocity_m_s: float
    state: str
    homed: bool
    at_target: bool
    at_limit: bool
    fault_code: int
    seq: int

    def to_message(self, node: int) -> can.Message:
        flags = ((FLAG_HOMED * self.homed) | (FLAG_AT_TARGET * self.at_target)
                 | (FLAG_AT_LIMIT * self.at_limit))
        data = (round(self.position_m * _DMM).to_bytes(3, "little", signed=True)
                + struct.pack("<hBBB", round(self.velocity_m_s * _MM), STATES.index(self.state) | flags,
                              self.fault_code, self.seq))
        return can.Message(arbitration_id=STATUS_BASE + node, is_extended_id=False, data=data)

    @classmethod
    def from_bytes(cls, data: bytes) -> StatusFrame:
        if len(data) != 8:
            raise ValueError(f"status frame has {len(data)} bytes, not 8")
        position = int.from_bytes(data[:3], "little", signed=True)
        velocity, byte6, fault, seq = struct.unpack("<hBBB", bytes(data[3:]))
        if byte6 & 0x07 >= len(STATES):
            raise ValueError(f"status frame has unknown state code {byte6 & 0x07}")
        return cls(position / _DMM, velocity / _MM, STATES[byte6 & 0x07], bool(byte6 & FLAG_HOMED),
                   bool(byte6 & FLAG_AT_TARGET), bool(byte6 & FLAG_AT_LIMIT), fault, seq)


@dataclass(frozen=True, slots=True)
class Reply:
    seq: int
    op: int
    reason: int

    def to_message(self, node: int) -> can.Message:
        return can.Message(arbitration_id=REPLY_BASE + node, is_extended_id=False,
                           data=bytes((self.seq, self.op, self.reason)))


def _why(reason: int) -> str:
    try:
        return Reason(reason).name
    except ValueError:
        return f"reason {reason}"
