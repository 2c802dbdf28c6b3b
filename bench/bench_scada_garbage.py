"""A garbage-sending SCADA client against four honest pollers, in one server.

One process sends random bytes, broken MBAP headers and headers promising more than comes,
reconnecting each time it is dropped; four connections poll a tank block (20 input registers) as
fast as they are answered. The sender is stopped and continued in alternating windows so the
machine's other load falls on both alike. Printed: reads per second in each, and their ratio
(``ratio``: 1.0 means garbage costs the pollers nothing). The suite only checks that nobody is
starved and the ratio stays above 0.5 (tests/controller/scada/test_robustness.py); this is the figure.

Run: ``.venv/bin/python bench/bench_scada_garbage.py``; prints one JSON object.
"""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.controller.scada.conftest import ServerThread, StandIn  # noqa: E402
from tests.controller.scada.test_robustness import GARBAGE, Readers  # noqa: E402

WINDOWS = int(os.environ.get("BENCH_GARBAGE_WINDOWS", "100"))
WINDOW_S = 0.12


def main() -> dict:
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)     # as `fishfarm run` sets it
    srv = ServerThread(StandIn())
    sender = subprocess.Popen([sys.executable, "-c", GARBAGE, str(srv.port), "1"], stdout=subprocess.PIPE, text=True)
    readers = Readers(srv.port)
    try:
        sender.stdout.readline()
        clean_rate, dirty_rate, _ = readers.alternate(sender, WINDOWS, WINDOW_S)
    finally:
        sender.kill()
        sender.wait()
        readers.close()
        dropped = srv.scada.server.broken
        srv.stop()
    return {"windows": WINDOWS, "clean_reads_s": round(clean_rate), "garbage_reads_s": round(dirty_rate),
            "ratio": round(dirty_rate / clean_rate, 3), "dropped_connections": dropped,
            "reader_errors": len(readers.errors)}


if __name__ == "__main__":
    from bench import no_arguments

    no_arguments(__doc__)
    print(json.dumps(main(), indent=2))
