"""Number tables for ``fishfarm calibrate import``: DLT coefficients (StereoMorph's cal_coeffs) and
plain 3x4 pairs as text, and the JSON form of a 3x4 pair. Faults are BadInput naming the file."""
from __future__ import annotations

import re

import numpy as np

from controller.cli.calib_io import calibration_json
from controller.cli.calib_opencv_file import OPENCV_NAMES, name_key, refuse_fisheye
from controller.errors import BadInput


def number(token: str) -> float | None:
    try:
        value = float(token.strip("\"'"))
    except ValueError:
        return None
    return value


def numbers_table(path: str, text: str) -> list[list[float]]:
    """Rows of numbers: '#' comments and blank lines skipped, a header (no number in it) skipped,
    a leading row name (quoted, or a word, or R's row index before two columns) dropped."""
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        tokens = [t for t in re.split(r"[\s,;]+", line.split("#", 1)[0].strip()) if t]
        if not tokens:
            continue
        values = [number(t) for t in tokens]
        if all(v is None for v in values):
            if rows:
                raise BadInput(path, f"line {lineno}", f"no number in {line.strip()[:40]!r} after the data began")
            continue                                   # a header
        if values[0] is None or (tokens[0][0] in "\"'"):
            tokens, values = tokens[1:], values[1:]    # a row name
        bad = [t for t, v in zip(tokens, values, strict=True) if v is None or not np.isfinite(v)]
        if bad:
            raise BadInput(path, f"line {lineno}", f"{bad[0]!r} is not a finite number")
        rows.append(values)
    return rows


def strip_row_index(rows: list[list[float]]) -> list[list[float]]:
    """Rows without R's row index 1..11 (write.table with unquoted row names) before two columns."""
    if len(rows) == 11 and {len(r) for r in rows} == {3} and [r[0] for r in rows] == list(range(1, 12)):
        return [r[1:] for r in rows]
    return rows


def dlt_table(path: str, rows: list[list[float]]) -> np.ndarray:
    table = np.array(rows, dtype=float) if len({len(r) for r in rows}) == 1 else None
    if table is not None and table.shape == (2, 11):
        table = table.T
    if table is None or table.shape != (11, 2):
        shape = "ragged rows" if table is None else f"{table.shape[0]} rows x {table.shape[1]} columns"
        raise BadInput(path, "coefficients", f"{shape}: expected 11 DLT coefficients x 2 cameras "
                                             "(one column per camera)")
    return table


# two 3x4 matrices as tools write them: P1's rows then P2's, one row per matrix, or all on one line.
# Any other layout of 24 numbers (a 12x2 DLT-12 table, P1 and P2 side by side) is not P1 then P2.
P34_LAYOUTS = ([4] * 6, [12, 12], [24])


def _shape(rows: list[list[float]]) -> str:
    lengths = [len(r) for r in rows]
    if len(set(lengths)) == 1:
        return f"{len(rows)} rows x {lengths[0]} columns"
    return f"{len(rows)} rows of {', '.join(map(str, lengths))} values"


def p34_text(path: str, rows: list[list[float]]) -> tuple[np.ndarray, np.ndarray]:
    values = np.array([v for r in rows for v in r], dtype=float)
    if values.size != 24:
        raise BadInput(path, "P1, P2", f"{values.size} numbers: expected 24 (two 3x4 matrices, P1 then P2)")
    if [len(r) for r in rows] not in P34_LAYOUTS:
        raise BadInput(path, "P1, P2", f"{_shape(rows)}: expected two 3x4 matrices as 6 rows of 4 (P1's rows, "
                                       "then P2's), 2 rows of 12 or one row of 24")
    return values[:12].reshape(3, 4), values[12:].reshape(3, 4)


def p34_json(path: str, text: str) -> dict:
    """A JSON object of CALIB.json's form (P1, P2 and its optional fields), checked for what would
    be silently wrong: another tool's name of a field (not read: its matrix lost), a fisheye model."""
    data = calibration_json(path, text)
    if not isinstance(data, dict):
        raise BadInput(path, None, "expected a JSON object with P1 and P2")
    for name in ("P1", "P2"):
        if data.get(name) is None:
            raise BadInput(path, name, "missing")
    size = data.get("image_size")
    if size is not None and not (isinstance(size, list) and len(size) == 2
                                 and all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size)):
        raise BadInput(path, "image_size", "expected [width, height] in pixels")
    refuse_fisheye(path, [(k, v) for k, v in data.items() if isinstance(v, (str, int, float))])
    for field, names in OPENCV_NAMES.items():
        own = "image_size" if field.startswith("image_") else field
        other = next((k for k in data if k != own and name_key(k) in {name_key(n) for n in names}), None)
        if other is not None:
            raise BadInput(path, other, f"another tool's name for {own}: CALIB.json's is {own} (not read as it is)")
    return data
