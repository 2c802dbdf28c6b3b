"""What every device kind shares: a name, its config section, the farm clock, open/close.

Modelled on python-can's BusABC: the base class owns the public API and its checks;
backends fill small ``_open``/``_close`` hooks. ``close()`` is safe to call twice.
"""
from __future__ import annotations

import abc
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict


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
            await self._open()
            self._opened = True

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
