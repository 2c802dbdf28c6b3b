"""Exceptions every backend of every device kind raises, real or simulated alike."""
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
