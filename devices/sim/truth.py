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
        self._closed = False
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(path, "a", encoding="utf-8", buffering=1)
        self.records: list[dict] = [] if path is None else None  # in memory for unit tests

    def write(self, kind: str, t: float, **fields) -> None:
        record = {"kind": kind, "t": round(t, 4), **fields}
        with self._lock:
            if self._fh is not None:
                self._fh.write(json.dumps(record) + "\n")
            elif not self._closed:
                self.records.append(record)
            # closed: a thread still running on the way out (a camera's frame) writes nothing

    def close(self, timeout_s: float = -1) -> bool:
        """Flush and close; later writes are dropped. ``timeout_s``: wait at most that long for a
        write in progress (from a watchdog about to end the process); False if it did not end."""
        if not self._lock.acquire(timeout=timeout_s):
            return False
        try:
            self._closed = True
            if self._fh is not None:
                self._fh.close()
                self._fh = None
        finally:
            self._lock.release()
        return True


def read_truth(path: str | Path) -> list[dict]:
    with open(path, encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]
