"""The Device base: open/close hooks, and what a failed open leaves behind."""
from __future__ import annotations

import asyncio

import pytest

from devices.base import Device, Section
from devices.errors import LinkDown


class Port(Device):
    """A device whose open takes a resource and then fails half-way, ``fail_opens`` times."""

    kind = "test"
    Config = Section

    def __init__(self, fail_opens: int):
        super().__init__("port", Section(kind="test", driver="test"), clock=None)
        self.fail_opens = fail_opens
        self.held = 0                 # resources taken and not given back
        self.closes = 0

    async def _open(self) -> None:
        self.held += 1
        if self.fail_opens:
            self.fail_opens -= 1
            raise LinkDown(self.name, "handshake failed")

    async def _close(self) -> None:
        self.closes += 1
        self.held = 0


def test_a_failed_open_releases_what_it_took_and_a_retry_opens():
    async def main():
        dev = Port(fail_opens=2)
        for _ in range(2):
            with pytest.raises(LinkDown):
                await dev.open()
            assert dev.held == 0                  # the half-open port was closed again
        await dev.open()
        assert dev.held == 1
        await dev.close()
        await dev.close()                          # safe twice
        return dev
    dev = asyncio.run(main())
    assert dev.held == 0 and dev.closes == 3


def test_close_after_a_failed_open_is_safe_and_open_after_close_refused():
    async def main():
        dev = Port(fail_opens=1)
        with pytest.raises(LinkDown):
            await dev.open()
        await dev.close()
        with pytest.raises(RuntimeError, match="after close"):
            await dev.open()
        return dev
    dev = asyncio.run(main())
    assert dev.held == 0
