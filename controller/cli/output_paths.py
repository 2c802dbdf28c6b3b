"""Each file a command writes is a file of its own, refused before any work: not a directory, not
another of the command's outputs, not one of its inputs (``--out GRID.csv`` would replace the grid
with its calibration; ``--json CALIB.json`` would lose the calibration)."""
from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from controller.errors import BadInput


def check_outputs(outputs: dict[str, str | Path | None], inputs: Iterable[str | Path | None]) -> None:
    """``outputs``: option -> path (None: not given); ``inputs``: every file the command reads.
    BadInput naming the path, the option and the fault."""
    given = {os.path.realpath(p) for p in inputs if p}
    seen: dict[str, str] = {}
    for option, path in outputs.items():
        if not path:
            continue
        if Path(path).is_dir():
            raise BadInput(str(path), option, "a directory, not a file")
        real = os.path.realpath(path)
        if real in seen:
            raise BadInput(str(path), option, f"the same file as {seen[real]}")
        if real in given:
            raise BadInput(str(path), option, "an input of this command: it would be written over")
        _check_directory(Path(real), str(path), option)
        seen[real] = option


def _check_directory(real: Path, path: str, option: str) -> None:
    """The file's directory exists or can be made there (nothing is made yet)."""
    parent = real.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise BadInput(path, option, f"cannot write: {parent} is a file, not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BadInput(path, option, f"cannot write: no permission in {parent}")
