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

# The repository's installed packages (vision, devices, controller: on the path wherever a script
# runs) are imported once in the parent, so each child only runs its script; hil_tests and bench are
# not, as whether a script finds those is what is checked.
PRELOAD = """
import importlib, pkgutil
import numpy, cv2, zenoh, matplotlib, pymodbus, click, pydantic
for _pkg in ("vision", "devices", "controller"):
    for _info in pkgutil.walk_packages(importlib.import_module(_pkg).__path__, _pkg + "."):
        if not _info.name.endswith("__main__"):
            importlib.import_module(_info.name)
"""

# One interpreter loads the libraries every script uses (PRELOAD), then forks a child per script:
# each puts the script's folder first on sys.path as ``make bench`` does and runs the file under the
# given module name with the given arguments (stdout and stderr to files, an alarm as its timeout);
# the parent reports each one's exit status and output. Under another name than ``__main__`` a
# script is only imported. A clean interpreter per script took 0.7 s each (52 s for the checks).
RUN_EACH = PRELOAD + """
import json, os, runpy, signal, sys, tempfile, traceback
how, paths = json.loads(sys.argv[1]), sys.argv[2:]
runs = {}
for path in paths:
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        pid = os.fork()
        if pid == 0:
            os.dup2(out.fileno(), 1)
            os.dup2(err.fileno(), 2)
            signal.alarm(120)
            code = 0
            try:
                sys.argv = [path, *how["args"]]
                sys.path[0] = os.path.dirname(path)
                runpy.run_path(path, run_name=how["run_name"])
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
                if not isinstance(e.code, int) and e.code is not None:
                    print(e.code, file=sys.stderr)
            except BaseException:
                traceback.print_exc()
                code = 1
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        _, status = os.waitpid(pid, 0)
        out.seek(0)
        err.seek(0)
        runs[os.path.basename(path)] = (os.waitstatus_to_exitcode(status), out.read().decode(errors="replace"),
                                        err.read().decode(errors="replace"))
print(json.dumps(runs))
"""
IMPORTED = "bench_script_under_test"


def _run_each(paths, args: list[str] = (), run_name: str = "__main__") -> dict[str, tuple[int, str, str]]:
    """Each script's (exit status, stdout, stderr) when run as ``python SCRIPT *args`` (or imported,
    ``run_name`` not ``__main__``)."""
    got = subprocess.run([sys.executable, "-c", RUN_EACH, json.dumps({"args": list(args), "run_name": run_name}),
                          *map(str, paths)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert got.returncode == 0, got.stderr.strip().splitlines()[-3:]
    return {name: tuple(run) for name, run in json.loads(got.stdout.strip().splitlines()[-1]).items()}


def _failures(runs: dict[str, tuple[int, str, str]]) -> dict[str, str]:
    return {name: (err.strip().splitlines() or [f"exit status {code}"])[-1]
            for name, (code, _, err) in runs.items() if code != 0}


def test_every_bench_script_imports_as_make_bench_runs_it():
    runs = _run_each(SCRIPTS, run_name=IMPORTED)
    assert sorted(runs) == sorted(s.name for s in SCRIPTS)
    assert _failures(runs) == {}


def test_a_script_that_does_not_import_is_named():
    """The check itself: a script reaching for a module nobody has is reported by name."""
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "bench_broken.py").write_text("import hil_tests_nowhere\n")
        (Path(d) / "bench_fine.py").write_text("import json\n")
        failed = _failures(_run_each([f"{d}/bench_broken.py", f"{d}/bench_fine.py"], run_name=IMPORTED))
    assert list(failed) == ["bench_broken.py"] and "hil_tests_nowhere" in failed["bench_broken.py"]


def test_the_scripts_are_found():
    assert {"bench_workers.py", "bench_growout.py", "__main__.py"} <= {s.name for s in SCRIPTS}


BENCHES = sorted((ROOT / "bench").glob("bench_*.py"))


def test_the_runner_reports_exit_status_and_output_as_a_process_would():
    """The check itself, on scripts written here: exit codes, stdout and stderr come back per script."""
    with tempfile.TemporaryDirectory() as d:
        scripts = {"bench_ok.py": "import sys\nprint('said', sys.argv[1:])\n",
                   "bench_refuses.py": "import argparse\nargparse.ArgumentParser().parse_args()\n",
                   "bench_raises.py": "raise RuntimeError('boom')\n",
                   "bench_guarded.py": "if __name__ == '__main__':\n    raise SystemExit(3)\n"}
        for name, text in scripts.items():
            (Path(d) / name).write_text(text)
        runs = _run_each([f"{d}/{name}" for name in scripts], ["--x"])
        imported = _run_each([f"{d}/bench_guarded.py"], ["--x"], run_name=IMPORTED)
    assert runs["bench_ok.py"][:2] == (0, "said ['--x']\n")
    assert runs["bench_refuses.py"][0] == 2 and "--x" in runs["bench_refuses.py"][2]
    assert runs["bench_raises.py"][0] == 1 and "RuntimeError: boom" in runs["bench_raises.py"][2]
    assert runs["bench_guarded.py"][0] == 3
    assert imported["bench_guarded.py"][0] == 0              # imported, its __main__ block does not run


def test_every_bench_script_refuses_an_argument_it_does_not_take_before_any_work():
    """Arguments were ignored by the scripts whose settings are environment variables:
    ``bench_growout.py --help`` ran the twelve-minute grow-out."""
    runs = _run_each(BENCHES, ["--no-such-setting"])
    refused = {name: (code, "--no-such-setting" in err) for name, (code, _, err) in runs.items()}
    assert refused == {s.name: (2, True) for s in BENCHES}, {n: err[-300:] for n, (_, _, err) in runs.items()}


def test_every_bench_script_says_what_it_measures_when_asked():
    runs = _run_each(BENCHES, ["--help"])
    said = {name: (code, len(out.strip()) > 40) for name, (code, out, _) in runs.items()}
    assert said == {s.name: (0, True) for s in BENCHES}


def test_make_bench_refuses_a_benchmark_there_is_not():
    r = subprocess.run([sys.executable, "-m", "bench", "grow_out"], cwd=ROOT, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "no benchmark 'grow_out'" in r.stderr and "growout" in r.stderr, r.stderr
