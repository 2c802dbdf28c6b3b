"""CALIB.json on disk: read, check, write. Faults are ``BadInput`` (exit 2, one line ``FILE: field: fault``).

The file's content is vision's (vision/calib_file.py, pure); the file is the command line's.
"""
from __future__ import annotations

import json
from pathlib import Path

from controller.errors import BadInput
from vision.calib_file import CalibrationError, StereoCalibration, calibration_from_json


class _Twice(ValueError):
    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def _once(pairs: list[tuple[str, object]]) -> dict:
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise _Twice(key)
        out[key] = value
    return out


def json_fields_once(path: str, text: str):
    """``json.loads`` of a calibration, a key given twice in one object refused (json keeps the
    last without a word: which matrix was meant is unknown)."""
    try:
        return json.loads(text, object_pairs_hook=_once)
    except _Twice as twice:
        raise BadInput(path, twice.key, "given twice: give it once") from None


def calibration_json(path: str, text: str):
    """``json_fields_once``, and JSON that Python cannot take as one line naming the file: a syntax
    error, a number of 4300+ digits (its message's advice to raise a limit left out), nesting past
    the parser's depth."""
    try:
        return json_fields_once(path, text)
    except ValueError as exc:                  # JSONDecodeError, the digits limit
        raise BadInput(path, None, f"not valid JSON: {str(exc).split('; use sys.')[0]}") from None
    except RecursionError:
        raise BadInput(path, None, "not valid JSON: nested too deep") from None


def load_calibration(path: str | Path) -> StereoCalibration:
    where = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")   # a BOM (Windows editors) is no fault
    except FileNotFoundError:
        raise BadInput(where, None, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInput(where, None, f"not valid JSON: {exc}") from None
    data = calibration_json(where, text)
    try:
        return calibration_from_json(data)
    except CalibrationError as exc:
        raise BadInput(where, exc.field, exc.fault) from None


def save_calibration(calib: StereoCalibration, path: str | Path) -> None:
    from controller.atomic_files import write_text_atomically
    write_text_atomically(path, json.dumps(calib.to_json(), indent=2) + "\n")
