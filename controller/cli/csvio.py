"""Numeric CSV files of the command line (GRID.csv, PAIRS.csv, ...): exact header, float cells.

``read_table`` parses with numpy's C reader (a million rows in well under a second) and, only when
that fails or finds NaN/inf, re-reads the file line by line to say exactly where the fault is:
``FILE: line 7, column u2: not a number: 'abc'``. Faults are ``BadInput`` (exit 2, one line).
``text_cell`` guards the text cells of the CSV files written with names and reasons in them.
"""
from __future__ import annotations

import csv
import io
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from controller.atomic_files import write_file_atomically
from controller.errors import BadInput

# the most a pixel in these files may be either way (no image is a million pixels wide), and a world
# coordinate (mm or m: site coordinates, a UTM easting in mm, stay well within); beyond, a typo
PIXELS_MAX = 1e6
WORLD_MAX = 1e12
# a spreadsheet takes a cell starting with one of these for a formula (=HYPERLINK(...), +cmd|...):
# OWASP's list for CSV injection
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def text_cell(value):
    """``value`` as a CSV cell: text a spreadsheet would run as a formula behind a single quote
    (OWASP), shown as written; numbers as they are (-3.5 stays a number)."""
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value


def _read_text(path: str | Path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise BadInput(str(path), None, "no such file") from None
    except IsADirectoryError:
        raise BadInput(str(path), None, "is a directory, expected a CSV file") from None
    except UnicodeDecodeError:
        raise BadInput(str(path), None, "not UTF-8 text (expected a CSV file)") from None
    except OSError as exc:
        raise BadInput(str(path), None, f"cannot read: {exc.strerror or exc}") from None


def _check_header(where: str, line: str, header: Sequence[str]) -> None:
    found = [cell.strip() for cell in next(csv.reader([line]), [])]
    if found != list(header):
        raise BadInput(where, "header", f"expected '{','.join(header)}', found '{','.join(found)}'")


def number(cell: str, where: str, lineno: int, column: str) -> float:
    """A finite float from a CSV cell, or BadInput naming file, line and column. Python's own
    spellings no CSV writer uses (``1_000``, digits of other scripts) are not numbers here."""
    try:
        if "_" in cell or not cell.isascii():
            raise ValueError(cell)
        value = float(cell)
    except ValueError:
        raise BadInput(where, f"line {lineno}, column {column}", f"not a number: {cell.strip()!r}") from None
    if not math.isfinite(value):
        raise BadInput(where, f"line {lineno}, column {column}", f"{cell.strip()} is not a finite number")
    return value


def _scan(where: str, lines: list[str], header: Sequence[str]) -> np.ndarray:
    """Slow path: parse line by line, raising at the first bad cell with its line and column."""
    rows = []
    for lineno, cells in enumerate(csv.reader(lines[1:]), start=2):
        if not cells or (len(cells) == 1 and not cells[0].strip()):
            continue                    # a blank line; a row of empty cells (",,,") is a row, refused below
        if len(cells) != len(header):
            raise BadInput(where, f"line {lineno}", f"{len(cells)} fields, expected {len(header)}")
        rows.append([number(cell, where, lineno, name) for name, cell in zip(header, cells, strict=True)])
    return np.array(rows, dtype=float).reshape(-1, len(header))


def read_table(path: str | Path, header: Sequence[str], limit: float | Sequence[float] | None = None) -> np.ndarray:
    """Float array (rows, len(header)) of a CSV whose first line is exactly ``header``.

    Blank lines are skipped; a file with a header and no rows gives a (0, k) array. Empty file,
    other header, wrong field count, non-numeric, NaN or infinite cells, and with ``limit`` (one
    for all columns, or one per column) a cell beyond ±limit (1e300 px is finite, and overflows
    what is computed from it): BadInput naming the file, the line and the column.
    """
    data = _read_table(path, header)
    if limit is not None and data.size:
        bound = np.broadcast_to(np.asarray(limit, dtype=float), (len(header),))
        beyond = np.argwhere(np.abs(data) > bound)
        if len(beyond):
            r, c = (int(x) for x in beyond[0])
            lines = _read_text(path).splitlines()
            lineno = [i for i, line in enumerate(lines[1:], start=2) if line.strip()][r]
            raise BadInput(str(path), f"line {lineno}", f"column {header[c]}: {data[r, c]:g} is out of range "
                                                        f"(at most {bound[c]:g} either way)")
    return data


def _read_table(path: str | Path, header: Sequence[str]) -> np.ndarray:
    where = str(path)
    text = _read_text(path)
    lines = text.splitlines()
    if not text.strip():
        raise BadInput(where, None, f"empty file (expected header '{','.join(header)}')")
    _check_header(where, lines[0], header)
    body = [line for line in lines[1:] if line.strip()]
    if not body:
        return np.empty((0, len(header)))
    try:
        data = np.loadtxt(io.StringIO("\n".join(body)), delimiter=",", dtype=float, ndmin=2)
        if data.shape[1] == len(header) and np.all(np.isfinite(data)):
            return data
    except ValueError:
        pass
    return _scan(where, lines, header)   # raises with the exact place, or parses what numpy would not


def write_table(path: str | Path | None, header: Sequence[str], data: np.ndarray, fmt: str = "%.6f") -> None:
    """Write ``data`` under ``header``; to stdout when ``path`` is None. Write failure: BadInput."""
    data = np.asarray(data, dtype=float).reshape(-1, len(header))
    if path is None:
        try:
            _write(sys.stdout, header, data, fmt)
            sys.stdout.flush()
        except BrokenPipeError:       # `... | head`: the reader left, nothing more to say
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        return
    write_file_atomically(path, lambda fh: _write(fh, header, data, fmt))


def _write(fh, header: Sequence[str], data: np.ndarray, fmt: str) -> None:
    fh.write(",".join(header) + "\n")
    if len(data):
        np.savetxt(fh, data, fmt=fmt, delimiter=",")
