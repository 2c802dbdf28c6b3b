"""Ground truth of a simulated run, one JSON object a line, for tests to judge the controller.

Kinds written: ``episode_start``/``episode_end`` (tank, rate_hz, why), ``burst`` (tank, sensor,
duration_s), ``sensor_fault`` (tank, sensor, fault, until), ``fed`` (tank, grams: what the fish
got), ``auger_start`` (tag, run_s: a START the PLC accepted),
``delivered`` (tank or null, grams: what left the chute over that tank, or between tanks;
one record per place the chute passed between two looks at the dispenser, ``t`` when it left
that place), ``auger_run`` (tag, t_start, physical_g, measured_g, jammed; ``power_cut`` and measured_g null
for a run a power cut ended uncounted), ``jam`` (tag), ``dispenser_power_cycle`` (count), and at
the end ``contact_hub`` (sent, dropped) and ``dispenser_total`` (physical_g). Every record has
``t`` in farm seconds.
"""
from __future__ import annotations

import json
import threading
from pathlib import Path


class TruthLog:
    def __init__(self, path: str | Path | None):
        self._lock = threading.Lock()
        self._fh = None
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(path, "a", encoding="utf-8", buffering=1)
        self.records: list[dict] = [] if path is None else None  # in memory for unit tests

    def write(self, kind: str, t: float, **fields) -> None:
        record = {"kind": kind, "t": round(t, 4), **fields}
        with self._lock:
            if self._fh is not None:
                self._fh.write(json.dumps(record) + "\n")
            else:
                self.records.append(record)

    def close(self) -> None:
        with self._lock:
            if self._fh is not None:
                self._fh.close()
                self._fh = None


def read_truth(path: str | Path) -> list[dict]:
    with open(path, encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]
