"""CALIB.json on disk: read, check, write. Faults are ``BadInput`` (exit 2, one line ``FILE: field: fault``).

The file's content is vision's (vision/calib_file.py, pure); the file is the command line's.
"""
from __future__ import annotations

import json
from pathlib import Path

from controller.errors import BadInput
from vision.calib_file import CalibrationError, StereoCalibration, calibration_from_json


def load_calibration(path: str | Path) -> StereoCalibration:
    where = str(path)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BadInput(where, None, "no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BadInput(where, None, f"not valid JSON: {exc}") from None
    try:
        return calibration_from_json(data)
    except CalibrationError as exc:
        raise BadInput(where, exc.field, exc.fault) from None


def save_calibration(calib: StereoCalibration, path: str | Path) -> None:
    from controller.atomic_files import write_text_atomically
    write_text_atomically(path, json.dumps(calib.to_json(), indent=2) + "\n")
