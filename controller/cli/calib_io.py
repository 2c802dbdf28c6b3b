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
    keys = [k for k, _ in pairs]
    for k in keys:
        if keys.count(k) > 1:
            raise _Twice(k)
    return dict(pairs)


def json_fields_once(path: str, text: str):
    """``json.loads`` of a calibration, a key given twice in one object refused (json keeps the
    last without a word: which matrix was meant is unknown)."""
    try:
        return json.loads(text, object_pairs_hook=_once)
    except _Twice as twice:
        raise BadInput(path, twice.key, "given twice: give it once") from None


def load_calibration(path: str | Path) -> StereoCalibration:
    where = str(path)
    try:
        data = json_fields_once(where, Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BadInput(where, None, "no such file") from None
    except (OSError, ValueError) as exc:           # ValueError: JSONDecodeError, a number of 4300+ digits
        raise BadInput(where, None, f"not valid JSON: {str(exc).split('; use sys.')[0]}") from None
    except RecursionError:
        raise BadInput(where, None, "not valid JSON: nested too deep") from None
    try:
        return calibration_from_json(data)
    except CalibrationError as exc:
        raise BadInput(where, exc.field, exc.fault) from None


def save_calibration(calib: StereoCalibration, path: str | Path) -> None:
    from controller.atomic_files import write_text_atomically
    write_text_atomically(path, json.dumps(calib.to_json(), indent=2) + "\n")
