"""Benchmarks: each ``bench_*.py`` is a script printing one JSON object of figures."""
from __future__ import annotations

import sys
from collections.abc import Iterable
from pathlib import Path


def no_arguments(doc: str | None, takes: Iterable[str] = ()) -> list[str]:
    """For a benchmark whose settings are environment variables, called first: ``-h``/``--help``
    prints its docstring and exits 0, an argument not among ``takes`` is refused (exit 2); the
    arguments otherwise. Arguments were ignored: ``bench_growout.py --help`` ran the twelve-minute
    grow-out."""
    args, takes = sys.argv[1:], list(takes)
    if args[:1] in (["-h"], ["--help"]):
        print((doc or "").strip())
        raise SystemExit(0)
    unknown = [a for a in args if a not in takes]
    if unknown:
        can = f"takes {', '.join(takes)}" if takes else "takes no arguments"
        print(f"{Path(sys.argv[0]).name}: {can}, not {unknown[0]!r} (its settings: --help)", file=sys.stderr)
        raise SystemExit(2)
    return args
