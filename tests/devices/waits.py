"""Waiting for a condition that another thread or process brings about: polled, with a deadline
that fails the test (never a sleep that hopes the thing has happened)."""
from __future__ import annotations

import asyncio
import time


async def until(pred, timeout: float = 5.0, what: str = "condition"):
    """Poll ``pred()`` until it returns something true (returned); AssertionError after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        got = pred()
        if got:
            return got
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not met in {timeout} s")
        await asyncio.sleep(0.002)
