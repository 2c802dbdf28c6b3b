"""Benchmarks: each ``bench_*.py`` is a script printing one JSON object of figures."""
from __future__ import annotations

import sys
from pathlib import Path


def no_arguments(doc: str | None) -> None:
    """For a benchmark whose settings are environment variables, called first: ``-h``/``--help``
    prints its docstring and exits 0, any other argument is refused (exit 2). Arguments were
    ignored: ``bench_growout.py --help`` ran the twelve-minute grow-out."""
    args = sys.argv[1:]
    if not args:
        return
    if args[0] in ("-h", "--help"):
        print((doc or "").strip())
        raise SystemExit(0)
    print(f"{Path(sys.argv[0]).name}: takes no arguments, not {args[0]!r} (its settings: --help)", file=sys.stderr)
    raise SystemExit(2)
