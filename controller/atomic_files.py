"""A command's output file appears whole or not at all: written beside its name, then renamed into
place. A reader never sees half a file, and a command killed or failing mid-write leaves the file
that was there before (a CALIB.json being replaced) as it was.

A name that is a symbolic link keeps pointing where it did: the file it names is the one replaced.
A device or a pipe (``--json /dev/null``, ``--csv /dev/stdout``, a FIFO) is written into, never
replaced: renaming over it put a plain file where the system's /dev/null had been. ``-`` is the
standard output, as for most Unix tools (``--json -``); so are /dev/stdout and its aliases. The
standard output is written through the process's own stream at its position, never opened by name:
opened by name it was truncated (``--out - >> calibrations.log`` lost the log), or, when the shell
had sent it to a file, renamed over (and what the command printed after went to the replaced file,
lost). A command whose data goes to the standard output prints its report on the standard error."""
from __future__ import annotations

import contextlib
import glob
import io
import os
import stat
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

from controller.errors import BadInput


def beside(target: Path) -> Path:
    """The file written before it takes ``target``'s name: one per process (two commands writing one
    name do not write into each other). The ones left by writers that are gone (killed outright,
    SIGKILL: nothing ran after) are swept first, else each kill left one more for good."""
    _sweep(target)
    # an ordinary open of this name, not mkstemp: the file gets the user's umask like any other
    return target.with_name(f".{target.name}.{os.getpid()}.part")


def _sweep(target: Path) -> None:
    prefix = f".{target.name}."
    with contextlib.suppress(OSError):
        for left in target.parent.glob(f"{glob.escape(prefix)}*.part"):
            pid = left.name[len(prefix):-len(".part")]
            if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)):
                with contextlib.suppress(OSError):
                    left.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        pass                    # another user's process, or no pid at all: not ours to sweep
    return True


STDOUT_NAMES = frozenset({"-", "/dev/stdout", "/dev/fd/1", "/proc/self/fd/1"})


def is_stdout(path: str | Path | None) -> bool:
    """The output option names the standard output (module docstring)."""
    return path is not None and str(path) in STDOUT_NAMES


def to_stdout(data: bytes) -> None:
    """``data`` onto the standard output, after whatever the process printed there before."""
    sys.stdout.flush()
    out = getattr(sys.stdout, "buffer", None)
    if out is None:                     # a text-only stream (some test harnesses)
        sys.stdout.write(data.decode("utf-8"))
    else:
        out.write(data)
        out.flush()


def named(path: str | Path) -> Path:
    """The file an output option names: ``-`` is the standard output (before, it made a file '-')."""
    return Path("/dev/stdout") if str(path) == "-" else Path(path)


def special(target: Path) -> bool:
    """A device, a pipe or a socket (through any links): written into, not replaced."""
    try:
        mode = target.stat().st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def _real(target: Path) -> Path:
    return Path(os.path.realpath(target)) if target.is_symlink() else target


def _take_name(tmp: Path, target: Path) -> None:
    if target.is_file():            # a file replaced keeps its permissions (a CALIB.json made private)
        os.chmod(tmp, target.stat().st_mode & 0o7777)
    os.replace(tmp, target)


def replace_atomically(path: str | Path, write: Callable[[str], None]) -> None:
    """``write(tmp)`` fills a file beside ``path`` (same directory, so the rename is atomic), which
    then takes its name. OSError becomes BadInput naming ``path``."""
    if is_stdout(path):
        _write_stdout(path, write)
        return
    target = named(path)
    if special(target):
        try:
            write(str(target))
        except OSError as exc:
            raise BadInput(str(path), None, f"cannot write: {exc.strerror or exc}") from None
        return
    target = _real(target)
    tmp = beside(target)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        write(str(tmp))
        _take_name(tmp, target)
    except OSError as exc:
        raise BadInput(str(path), None, f"cannot write: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):      # (no directory to hold it: nothing was written)
            tmp.unlink(missing_ok=True)


def _write_stdout(path: str | Path, write: Callable[[str], None]) -> None:
    """``write(tmp)`` into a private file, then its bytes onto the standard output: whole or not at all."""
    fd, tmp = tempfile.mkstemp(prefix=".fishfarm-stdout.")
    os.close(fd)
    try:
        write(tmp)
        to_stdout(Path(tmp).read_bytes())
    except OSError as exc:
        raise BadInput(str(path), None, f"cannot write: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def write_file_atomically(path: str | Path, fill: Callable[[TextIO], None]) -> None:
    """``fill(fh)`` writes the text of ``path`` (UTF-8, newlines as written) into the file beside it."""
    def write(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fill(fh)
    replace_atomically(path, write)


def write_text_atomically(path: str | Path, text: str) -> None:
    write_file_atomically(path, lambda fh: fh.write(text))


class PendingFile:
    """A file written over a long run (a survey's OUT.json and FISH.csv): open beside ``path`` from
    the start, so an unwritable place fails before any work, and given its name by ``commit`` only.
    ``discard`` (after a failure, a signal) leaves whatever file was there as it was; both are safe
    to call twice."""

    def __init__(self, path: str | Path, what: str):
        self.path, self.what, self.name = named(path), what, str(path)
        self.stdout = is_stdout(path)
        self.special = self.stdout or special(self.path)
        if self.special:             # kept until the commit, which writes it into the device or pipe
            if not self.stdout and not os.access(self.path, os.W_OK):
                raise BadInput(str(path), None, f"cannot write {what}: permission denied")
            self.file: TextIO = io.StringIO()
            return
        self.path = _real(self.path)
        self.tmp = beside(self.path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.file = open(self.tmp, "w", encoding="utf-8", newline="")
        except OSError as exc:
            raise BadInput(str(path), None, f"cannot write {what}: {exc.strerror or exc}") from None

    def commit(self) -> None:
        if self.file.closed:
            return
        if self.special:
            text = self.file.getvalue()
            self.file.close()
            if self.stdout:
                try:
                    to_stdout(text.encode("utf-8"))
                except OSError as exc:
                    raise BadInput(self.name, None, f"cannot write {self.what}: {exc.strerror or exc}") from None
                return
            try:
                with open(self.path, "w", encoding="utf-8", newline="") as fh:
                    fh.write(text)
            except OSError as exc:
                raise BadInput(str(self.path), None, f"cannot write {self.what}: {exc.strerror or exc}") from None
            return
        self.file.close()
        try:
            _take_name(self.tmp, self.path)
        except OSError as exc:
            self.discard()
            raise BadInput(str(self.path), None, f"cannot write: {exc.strerror or exc}") from None

    def discard(self) -> None:
        self.file.close()
        if self.special:
            return
        with contextlib.suppress(OSError):
            self.tmp.unlink(missing_ok=True)
