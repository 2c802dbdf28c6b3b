"""A survey's files: OUT.json (the contract), FISH.csv (every fish, units in the headers) and the
histogram page (``--plot``).

The fish list of a long video does not stay in memory: entries are spooled to a temporary file
as they come and copied into OUT.json at the end. OUT.json and FISH.csv are written beside their
final names and renamed into place (a reader never sees half a file; a survey that fails or is
stopped leaves the files that were there as they were). Both are opened before the first pair is
measured, and the page's directory checked (controller/cli/output_paths.py), so an unwritable path
fails at once, not after an hour of footage.
"""
from __future__ import annotations

import json
import math
import tempfile

import numpy as np

from controller.atomic_files import PendingFile
from vision.survey_types import FishMeasurement

CSV_HEADER = ("frame", "track", "length_cm", "weight_g", "condition_k", "score",
              "snout_x_mm", "snout_y_mm", "snout_z_mm", "fork_x_mm", "fork_y_mm", "fork_z_mm",
              "snout_u1_px", "snout_v1_px", "snout_u2_px", "snout_v2_px",
              "fork_u1_px", "fork_v1_px", "fork_u2_px", "fork_v2_px", "outlier")


def _finite(x: float, digits: int) -> float | None:
    x = float(x)
    return round(x, digits) if math.isfinite(x) else None


def _vec(v, digits: int = 2) -> list:
    return [_finite(x, digits) for x in np.asarray(v, dtype=float).reshape(-1)]


def fish_entry(frame: int, track: int, fish: FishMeasurement, weight_g: float) -> dict:
    """One ``fish`` element of OUT.json: the contract's fields, then the optional ones."""
    length = fish.length_cm
    return {"frame": int(frame), "length_cm": _finite(length, 3), "weight_g": _finite(weight_g, 2),
            "snout_mm": _vec(fish.snout_mm), "fork_mm": _vec(fish.fork_mm), "score": _finite(fish.score, 4),
            "track": int(track),
            "condition_k": _finite(100.0 * weight_g / length ** 3, 4) if length > 0 else None,
            "snout_px": [_vec(r) for r in np.asarray(fish.snout_px, dtype=float).reshape(2, 2)],
            "fork_px": [_vec(r) for r in np.asarray(fish.fork_px, dtype=float).reshape(2, 2)],
            "quality": {str(k): _finite(v, 4) for k, v in fish.quality.items()}}


class SurveyFiles:
    """OUT.json (+ FISH.csv) of one survey: fish spooled as they come, both files written by
    ``finish`` (then each entry's ``outlier`` is known); ``close`` after a failure."""

    def __init__(self, json_path: str, csv_path: str | None = None):
        self._json = PendingFile(json_path, "OUT.json")
        self._spool = tempfile.TemporaryFile("w+", encoding="utf-8")
        self.entries = 0
        self._csv_file = PendingFile(csv_path, "the CSV") if csv_path else None
        self._csv = self._csv_file.file if self._csv_file else None
        if self._csv:
            self._csv.write(",".join(CSV_HEADER) + "\n")

    def add(self, entry: dict) -> None:
        self._spool.write(json.dumps(entry, allow_nan=False) + "\n")
        self.entries += 1

    def _csv_row(self, entry: dict) -> None:
        row = [entry["frame"], entry["track"], entry["length_cm"], entry["weight_g"], entry["condition_k"],
               entry["score"], *entry["snout_mm"], *entry["fork_mm"],
               *entry["snout_px"][0], *entry["snout_px"][1], *entry["fork_px"][0], *entry["fork_px"][1],
               int(entry["outlier"])]
        self._csv.write(",".join("" if v is None else str(v) for v in row) + "\n")

    def finish(self, head: dict, tail: dict, counted_tracks: set[int]) -> None:
        """OUT.json = ``head`` fields, the spooled ``fish`` list (each entry's ``outlier``: its
        track is not among ``counted_tracks``, those the statistics rest on), then ``tail`` fields."""
        out = self._json.file
        out.write("{" + json.dumps(head, allow_nan=False)[1:-1] + ',\n "fish": [')
        self._spool.seek(0)
        for i, line in enumerate(self._spool):
            entry = json.loads(line)
            entry["outlier"] = entry["track"] not in counted_tracks
            out.write(("\n  " if i == 0 else ",\n  ") + json.dumps(entry, allow_nan=False))
            if self._csv:           # (rows at the end, when the outliers are known)
                self._csv_row(entry)
        out.write("\n ],\n " + json.dumps(tail, allow_nan=False, indent=1)[1:].lstrip() + "\n")
        if self._csv_file:
            self._csv_file.commit()
        self._json.commit()
        self.close()

    def close(self) -> None:
        """Safe to call twice; after a failure, neither file replaces what was there (no .part left)."""
        self._spool.close()
        for pending in (self._json, self._csv_file):
            if pending:
                pending.discard()
