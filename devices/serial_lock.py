"""One process at a time on a serial device: an exclusive advisory lock (flock), as pyserial's
``exclusive=True`` takes it, for ports opened through libraries that do not ask for one (python-can's
slcan). Two drivers reading one port each get half its bytes; a second controller, or a driver
retrying the path of a device that went away and whose number the system gave to another
(pseudo-terminals are numbered lowest first), would do exactly that."""
from __future__ import annotations

import contextlib
import fcntl
import os


class PortInUse(OSError):
    """Another process holds the port's lock."""


def hold(path: str) -> int | None:
    """A descriptor holding ``path``'s exclusive lock until closed (``release``); None when the
    path is not a local device (a URL, a name the library resolves). PortInUse when another
    process holds it."""
    if not path.startswith("/") or not os.path.exists(path):
        return None
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise PortInUse(f"{path} is in use by another process (locked)") from None
    return fd


def release(fd: int | None) -> None:
    if fd is not None:
        with contextlib.suppress(OSError):
            os.close(fd)
