"""``make bench``: run every benchmark script as its own process (so each gets a clean, pinned
interpreter) and print one JSON line per benchmark: {"bench": name, ...figures}.

``python -m bench NAME ...`` runs only those (names without the ``bench_`` prefix)."""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    scripts = sorted(HERE.glob("bench_*.py"))
    if argv[:1] in (["-h"], ["--help"]):
        print(__doc__.strip())
        return 0
    if argv:
        wanted = {f"bench_{name.removeprefix('bench_').removesuffix('.py')}.py": name for name in argv}
        unknown = [name for file, name in wanted.items() if not (HERE / file).is_file()]
        if unknown:       # (it ran nothing and exited 0)
            print(f"python -m bench: no benchmark {unknown[0]!r}; there are "
                  f"{', '.join(s.stem.removeprefix('bench_') for s in scripts)}", file=sys.stderr)
            return 2
        scripts = [s for s in scripts if s.name in wanted]
    failed = 0
    for script in scripts:
        name = script.stem.removeprefix("bench_")
        started = time.monotonic()
        proc = subprocess.run([sys.executable, str(script)], cwd=HERE.parent, capture_output=True, text=True)
        start = proc.stdout.find("{")
        try:
            figures = json.JSONDecoder().raw_decode(proc.stdout[start:])[0] if start >= 0 else None
        except json.JSONDecodeError:
            figures = None
        if proc.returncode != 0 or not isinstance(figures, dict):
            failed += 1
            print(json.dumps({"bench": name, "error": (proc.stderr.strip().splitlines() or ["no output"])[-1]}))
            continue
        print(json.dumps({"bench": name, "wall_s": round(time.monotonic() - started, 1), **figures}), flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
