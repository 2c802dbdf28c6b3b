"""Exceptions every backend of every device kind raises, real or simulated alike, and ``BadInput``.

``BadInput`` lives here, at the bottom of the layers, because a device's config section is
validated by the device's own model (devices/sections.py) and faults there must reach the
user exactly as the controller's own do; ``controller.errors`` re-exports it.
"""
from __future__ import annotations


class DeviceError(Exception):
    """Base of everything a device can do wrong. ``device`` names it in the farm's config."""

    def __init__(self, device: str, text: str):
        super().__init__(f"{device}: {text}")
        self.device = device
        self.text = text


class DeviceTimeout(DeviceError):
    """The device did not answer in time (Modbus reply missing, CAN status frames gone quiet)."""


class LinkDown(DeviceError):
    """The line to the device is gone (port closed, connection refused or reset)."""


class DeviceFault(DeviceError):
    """The device answered and reports a fault of its own (jammed auger, drive fault, exception code)."""


class ProtocolError(DeviceError):
    """The device said something the protocol does not allow (malformed line, bad checksum)."""


class BadInput(Exception):
    """Input the user can fix: a file, a field, a value. ``str()`` is the one line they read.

    Build it as ``BadInput(path, field, fault)`` so every message names where the fault is.
    """

    def __init__(self, where: str, field: str | None = None, fault: str | None = None):
        parts = [str(where)]
        if field:
            parts.append(str(field))
        if fault:
            parts.append(str(fault))
        super().__init__(": ".join(parts))
