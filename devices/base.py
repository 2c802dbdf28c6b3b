"""What every device kind shares: a name, its config section, the farm clock, open/close.

Modelled on python-can's BusABC: the base class owns the public API and its checks;
backends fill small ``_open``/``_close`` hooks. ``close()`` is safe to call twice.
An ``_open`` that fails part-way is followed at once by ``_close``, so whatever it had taken
(a port, a client) is released; ``_close`` must therefore cope with a half-open device.
"""
from __future__ import annotations

import abc
import logging
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict

log = logging.getLogger(__name__)


class Section(BaseModel):
    """A device's config section. Unknown keys are errors (they are usually typos)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: str
    driver: str


class Device(abc.ABC):
    kind: ClassVar[str]
    Config: ClassVar[type[Section]]

    def __init__(self, name: str, config: Section, clock: Any):
        self.name = name
        self.config = config
        self.clock = clock
        self._opened = False
        self._closed = False

    async def open(self) -> None:
        if self._closed:
            raise RuntimeError(f"{self.name}: open() after close()")
        if not self._opened:
            try:
                await self._open()
            except BaseException:
                await self._release_half_open()
                raise
            self._opened = True

    async def _release_half_open(self) -> None:
        # close() skips _close() for a device that never opened: release here, or a port leaks.
        try:
            await self._close()
        except Exception as exc:      # the open's own error is the one worth raising
            log.debug("%s: closing after a failed open: %s", self.name, exc)

    async def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._opened:
            await self._close()

    async def __aenter__(self):
        await self.open()
        return self

    async def __aexit__(self, *exc):
        await self.close()

    @abc.abstractmethod
    async def _open(self) -> None: ...

    @abc.abstractmethod
    async def _close(self) -> None: ...
