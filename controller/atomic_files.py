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
