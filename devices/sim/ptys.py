"""What the twins served on a pseudo-terminal share: the raw pty they keep, the task they stop."""
from __future__ import annotations

import asyncio
import contextlib
import os
import tty


def open_pty() -> tuple[int, int, str]:
    """A raw pty: (master, non-blocking; slave, kept open by the twin; the slave's path).

    Keeping our own slave fd open means writes never fail with EIO while no reader is attached,
    and the master reads no EIO until the host opens the port."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


def close_pty(*fds: int) -> None:
    """Close both ends (those still open, >= 0): a reader then sees the port vanish."""
    for fd in fds:
        if fd >= 0:
            os.close(fd)


async def end_task(task: asyncio.Task | None) -> None:
    """Cancel ``task`` and wait for it to end (None: nothing to do)."""
    if task is not None:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def write_lines(master: int, pending: bytes, lines, max_pending: int) -> tuple[bytes, int]:
    """Write what is ``pending`` and then ``lines`` to the pty without blocking; returns the unsent
    tail (the next call's ``pending``) and how many lines were dropped: all of them when more than
    ``max_pending`` bytes still wait (no reader, or one too slow), as a real device's UART drops."""
    dropped = 0
    if len(pending) > max_pending:
        dropped, lines = len(lines), ()
    data = pending + b"".join(lines)
    if not data:
        return b"", dropped
    try:
        n = os.write(master, data)
    except BlockingIOError:
        n = 0
    return data[n:], dropped
