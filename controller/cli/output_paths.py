"""Each file a command writes is a file of its own, refused before any work: not a directory, not
another of the command's outputs, not one of its inputs (``--out GRID.csv`` would replace the grid
with its calibration; ``--json CALIB.json`` would lose the calibration)."""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from controller.atomic_files import beside, is_stdout, named
from controller.atomic_files import special as _special
from controller.errors import BadInput


def check_outputs(outputs: dict[str, str | Path | None], inputs: Iterable[str | Path | None]) -> None:
    """``outputs``: option -> path (None: not given); ``inputs``: every file the command reads.
    BadInput naming the path, the option and the fault."""
    inputs = [p for p in inputs if p]
    given = {os.path.realpath(p) for p in inputs}
    # a hard link is the same file under another name: realpath does not see it, the inode does
    given_files = {ident for p in inputs if (ident := _file_id(p)) is not None}
    seen: dict[str, str] = {}
    seen_files: dict[tuple[int, int], str] = {}
    on_stdout: str | None = None        # the option already writing to the standard output
    for option, path in outputs.items():
        if path is None:
            continue
        if not str(path).strip():      # it wrote nothing without a word (--png ''), or crashed (--json '')
            raise BadInput(option, None, f"{str(path)!r}: an empty path; give a file name")
        if Path(path).is_dir():
            raise BadInput(str(path), option, "a directory, not a file")
        if is_stdout(path):            # the shell's to check: one output there, else they mix
            if on_stdout is not None:
                raise BadInput(str(path), option, f"the standard output, as {on_stdout} is: they would mix")
            on_stdout = option
            continue
        target = named(path)
        if _special(target):           # /dev/null, a FIFO, a terminal: written into, never replaced
            if not os.access(target, os.W_OK):
                raise BadInput(str(path), option, "cannot write: permission denied")
            continue
        real, ident = os.path.realpath(path), _file_id(path)
        if real in seen or ident in seen_files:
            raise BadInput(str(path), option, f"the same file as {seen.get(real) or seen_files[ident]}")
        if real in given or ident in given_files:
            raise BadInput(str(path), option, "an input of this command: it would be written over")
        _check_directory(Path(real), str(path), option)
        seen[real] = option
        if ident is not None:
            seen_files[ident] = option


@contextlib.contextmanager
def report_beside(*outputs: str | Path | None) -> Iterator[None]:
    """What the command prints goes to the standard error while one of ``outputs`` is the standard
    output: ``--out - | jq`` reads the data alone (the report had been mixed into it)."""
    if any(is_stdout(p) for p in outputs):
        with contextlib.redirect_stdout(sys.stderr):
            yield
    else:
        yield


def _file_id(path) -> tuple[int, int] | None:
    """(device, inode) of an existing file, None otherwise."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def _check_directory(real: Path, path: str, option: str) -> None:
    """The file's directory exists or can be made there (nothing is made yet)."""
    parent = real.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise BadInput(path, option, f"cannot write: {parent} is a file, not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BadInput(path, option, f"cannot write: no permission in {parent}")
    if parent != real.parent:
        # the missing folders are made at the end, in ``parent``: tried for real here too (root
        # passes access() in /proc, where no folder can be made)
        try:
            os.rmdir(tempfile.mkdtemp(prefix=".fishfarm-trial-", dir=parent))
        except OSError as exc:
            raise BadInput(path, option, f"cannot write: {exc.strerror or exc}") from None
    else:
        # tried for real: root passes every access() check, and /proc or a read-only mount still
        # refuse the file (a --plot there failed after an hour's survey, with OUT.json written)
        trial = beside(real)
        try:
            trial.open("w").close()
            trial.unlink()
        except FileNotFoundError:         # the folder is there: /proc and /sys make no new files
            raise BadInput(path, option, f"cannot write: {parent} takes no new files") from None
        except OSError as exc:
            raise BadInput(path, option, f"cannot write: {exc.strerror or exc}") from None
