"""A command's output file appears whole or not at all: written beside its name, then renamed into
place. A reader never sees half a file, and a command killed or failing mid-write leaves the file
that was there before (a CALIB.json being replaced) as it was."""
from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from pathlib import Path

from controller.errors import BadInput


def replace_atomically(path: str | Path, write: Callable[[str], None]) -> None:
    """``write(tmp)`` fills a file beside ``path`` (same directory, so the rename is atomic), which
    then takes its name. OSError becomes BadInput naming ``path``."""
    target = Path(path)
    # an ordinary open, not mkstemp: the file gets the user's umask like any other they write
    tmp = target.with_name(f".{target.name}.{os.getpid()}.part")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        write(str(tmp))
        if target.is_file():        # a file replaced keeps its permissions (a CALIB.json made private)
            os.chmod(tmp, target.stat().st_mode & 0o7777)
        os.replace(tmp, target)
    except OSError as exc:
        raise BadInput(str(path), None, f"cannot write: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):      # (no directory to hold it: nothing was written)
            tmp.unlink(missing_ok=True)


def write_text_atomically(path: str | Path, text: str) -> None:
    replace_atomically(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


class PendingFile:
    """A file written over a long run (a survey's OUT.json and FISH.csv): open beside ``path`` from
    the start, so an unwritable place fails before any work, and given its name by ``commit`` only.
    ``discard`` (after a failure, a signal) leaves whatever file was there as it was; both are safe
    to call twice."""

    def __init__(self, path: str | Path, what: str):
        self.path = Path(path)
        self.tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.part")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.file = open(self.tmp, "w", encoding="utf-8", newline="")
        except OSError as exc:
            raise BadInput(str(path), None, f"cannot write {what}: {exc.strerror or exc}") from None

    def commit(self) -> None:
        if self.file.closed:
            return
        self.file.close()
        try:
            if self.path.is_file():
                os.chmod(self.tmp, self.path.stat().st_mode & 0o7777)
            os.replace(self.tmp, self.path)
        except OSError as exc:
            self.discard()
            raise BadInput(str(self.path), None, f"cannot write: {exc.strerror or exc}") from None

    def discard(self) -> None:
        self.file.close()
        with contextlib.suppress(OSError):
            self.tmp.unlink(missing_ok=True)
