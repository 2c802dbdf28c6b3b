"""Errors that reach the user as one line and exit status 2.

``BadInput`` is defined in devices/errors.py so that devices/ can raise it without importing
controller/ (the layers in DESIGN.md); this is the name the controller's code uses.
"""
from __future__ import annotations

from devices.errors import BadInput

__all__ = ["BadInput"]
