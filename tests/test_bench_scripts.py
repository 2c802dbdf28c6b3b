"""Every bench script imports as ``make bench`` (bench/__main__.py) runs it: as a file from the
repository's root, the script's own folder first on sys.path. Nothing runs (no ``__main__``): a
script reaching for a module beside the installed packages (hil_tests, bench) must put the root on
the path itself, or ``make bench`` reports it as an error after the others' minutes of work."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "bench").glob("*.py"))

IMPORT_AS_RUN = """
import importlib.util, sys
path = sys.argv[1]
sys.path[0] = sys.argv[2]
spec = importlib.util.spec_from_file_location("bench_script_under_test", path)
spec.loader.exec_module(importlib.util.module_from_spec(spec))
"""


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.name for s in SCRIPTS])
def test_bench_script_imports_as_make_bench_runs_it(script: Path):
    got = subprocess.run([sys.executable, "-c", IMPORT_AS_RUN, str(script), str(script.parent)],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert got.returncode == 0, got.stderr.strip().splitlines()[-1:]


def test_the_scripts_are_found():
    assert {"bench_workers.py", "bench_growout.py", "__main__.py"} <= {s.name for s in SCRIPTS}
