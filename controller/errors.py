"""Errors that reach the user as one line and exit status 2."""
from __future__ import annotations


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
