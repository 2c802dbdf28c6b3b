"""An event loop on a thread of its own, for the Modbus server.

On the controller's loop, a SCADA's e-stop waited for whatever held that loop: a ledger fsync, a
batch of contacts, a status built for a query (a flood of them had it 2-3 s late). The server now
reads, parses and answers on this loop, and the e-stop frame trips the latches here, before any of
that; the writes it takes still act on the controller's loop (``ScadaStore.act_loop``), where the
overrides, the audit and the ledger live."""
from __future__ import annotations

import asyncio
import contextlib
import threading

STOP_WAIT_S = 0.5          # wall: the thread's tasks cancelled, its loop stopped, within this (twice at most)


class ServingThread:
    def __init__(self, name: str = "scada-server"):
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_forever()
        finally:
            with contextlib.suppress(Exception):
                self.loop.close()

    async def run(self, coro):
        """``coro`` on this thread's loop, awaited from the caller's; cancelling the caller cancels it."""
        return await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(coro, self.loop))

    async def close(self, wait_s: float = STOP_WAIT_S) -> bool:
        """Cancel what runs on the thread (awaited, not blocking the caller's loop), stop its loop,
        join it for ``wait_s`` at most (a daemon thread: a stop never hangs on it); safe to call
        twice. True if the thread ended."""
        if self._thread.is_alive() and not self.loop.is_closed():
            with contextlib.suppress(Exception):       # (a loop stopping meanwhile, a task slow to go)
                await asyncio.wait_for(self.run(_cancel_all()), wait_s)
            with contextlib.suppress(RuntimeError):    # (its loop closed meanwhile)
                self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(wait_s)
        return not self._thread.is_alive()


async def _cancel_all() -> None:
    tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
    for task in tasks:
        task.cancel()
    if tasks:
        await asyncio.wait(tasks, timeout=STOP_WAIT_S / 2)
