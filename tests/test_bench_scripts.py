"""Every bench script imports as ``make bench`` (bench/__main__.py) runs it: as a file from the
repository's root, the script's own folder first on sys.path. Nothing runs (no ``__main__``): a
script reaching for a module beside the installed packages (hil_tests, bench) must put the root on
the path itself, or ``make bench`` reports it as an error after the others' minutes of work."""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "bench").glob("*.py"))

# One interpreter loads the libraries every script uses (not the repository's packages: whether a
# script finds those is the question), then forks a child per script: each child puts the script's
# folder first on sys.path as ``make bench`` does and imports it. A clean interpreter per script
# took 0.7 s each, 23 of them.
IMPORT_EACH_AS_RUN = """
import importlib.util, json, os, sys, traceback
import numpy, cv2, zenoh, matplotlib, pymodbus, click, pydantic
verdicts = {}
for path in sys.argv[1:]:
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        try:
            sys.path[0] = os.path.dirname(path)
            spec = importlib.util.spec_from_file_location("bench_script_under_test", path)
            spec.loader.exec_module(importlib.util.module_from_spec(spec))
            said = b""
        except BaseException:
            said = traceback.format_exc().strip().splitlines()[-1].encode() or b"failed"
        os.write(w, said)
        os._exit(0)
    os.close(w)
    with os.fdopen(r, "rb") as f:
        said = f.read().decode()
    _, status = os.waitpid(pid, 0)
    verdicts[os.path.basename(path)] = said or (None if status == 0 else f"exit status {status}")
print(json.dumps(verdicts))
"""


def test_every_bench_script_imports_as_make_bench_runs_it():
    got = subprocess.run([sys.executable, "-c", IMPORT_EACH_AS_RUN, *map(str, SCRIPTS)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert got.returncode == 0, got.stderr.strip().splitlines()[-3:]
    verdicts = json.loads(got.stdout.strip().splitlines()[-1])
    assert sorted(verdicts) == sorted(s.name for s in SCRIPTS)
    assert {name: said for name, said in verdicts.items() if said is not None} == {}


def test_a_script_that_does_not_import_is_named():
    """The check itself: a script reaching for a module nobody has is reported by name."""
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "bench_broken.py").write_text("import hil_tests_nowhere\n")
        (Path(d) / "bench_fine.py").write_text("import json\n")
        got = subprocess.run([sys.executable, "-c", IMPORT_EACH_AS_RUN, f"{d}/bench_broken.py", f"{d}/bench_fine.py"],
                             cwd=ROOT, capture_output=True, text=True, timeout=120)
    verdicts = json.loads(got.stdout.strip().splitlines()[-1])
    assert verdicts["bench_fine.py"] is None
    assert "hil_tests_nowhere" in verdicts["bench_broken.py"]


def test_the_scripts_are_found():
    assert {"bench_workers.py", "bench_growout.py", "__main__.py"} <= {s.name for s in SCRIPTS}


BENCHES = sorted((ROOT / "bench").glob("bench_*.py"))


def _run_each(args: list[str]) -> dict[str, subprocess.CompletedProcess]:
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(2) as pool:
        runs = pool.map(lambda s: subprocess.run([sys.executable, str(s), *args], cwd=ROOT, capture_output=True,
                                                 text=True, timeout=120), BENCHES)
        return {s.name: r for s, r in zip(BENCHES, runs, strict=True)}


def test_every_bench_script_refuses_an_argument_it_does_not_take_before_any_work():
    """Arguments were ignored by the scripts whose settings are environment variables:
    ``bench_growout.py --help`` ran the twelve-minute grow-out."""
    runs = _run_each(["--no-such-setting"])
    refused = {name: (r.returncode, "--no-such-setting" in r.stderr) for name, r in runs.items()}
    assert refused == {name: (2, True) for name in runs}, {n: runs[n].stderr[-300:] for n in runs}


def test_every_bench_script_says_what_it_measures_when_asked():
    runs = _run_each(["--help"])
    said = {name: (r.returncode, len(r.stdout.strip()) > 40) for name, r in runs.items()}
    assert said == {name: (0, True) for name in runs}


def test_make_bench_refuses_a_benchmark_there_is_not():
    r = subprocess.run([sys.executable, "-m", "bench", "grow_out"], cwd=ROOT, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "no benchmark 'grow_out'" in r.stderr and "growout" in r.stderr, r.stderr
