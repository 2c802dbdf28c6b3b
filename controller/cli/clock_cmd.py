"""``fishfarm clock``: make an elastic clock file for a simulated farm, or show one.

    fishfarm clock --out FILE --slow X --fast Y [--farm-start ISO|UNIX] [--await NAME ...]
    fishfarm clock --show FILE

The file (devices/elastic_clock.py) is what ``fishfarm sim --clock FILE`` and ``fishfarm run
--clock FILE`` share: farm time runs at ``--slow`` while any of them is busy and at ``--fast``
while all are idle. ``--await sim --await controller`` reserves their slots before they start, so
the clock stays slow until each has said what it needs (as hil_tests/farm.py does). ``--show``
prints the current segment and every slot as one JSON object. Bad input exits 2 with one line.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import click

from controller.errors import BadInput
from devices.clock import iso as _iso


@click.command()
@click.option("--out", "out", default=None, metavar="FILE", help="write a new clock file here")
@click.option("--show", "show", default=None, metavar="FILE", help="print this clock file's state (JSON)")
@click.option("--slow", type=float, default=None, help="farm seconds per wall second while anyone is busy")
@click.option("--fast", type=float, default=None, help="farm seconds per wall second while all are idle")
@click.option("--farm-start", default=None, metavar="ISO|UNIX", help="farm time now [default: the wall clock]")
@click.option("--await", "awaited", multiple=True, metavar="NAME",
              help="a process slot (sim, controller) held busy until that process speaks (repeatable)")
def clock(out, show, slow, fast, farm_start, awaited) -> None:
    """Make an elastic farm clock file (--out), or show one (--show)."""
    if (out is None) == (show is None):
        raise BadInput("--out/--show", None, "give one of them")
    if show is not None:
        click.echo(json.dumps(_state(show), indent=1))
        return
    _make(out, slow, fast, farm_start, awaited)


def _make(out: str, slow, fast, farm_start, awaited) -> None:
    from controller.history import parse_time
    from devices.elastic_clock import NSLOTS, create
    for name, value in (("--slow", slow), ("--fast", fast)):
        if value is None or not math.isfinite(value) or value <= 0:
            raise BadInput(name, None, f"{value}: a speed > 0 is required")
    if slow > fast:
        raise BadInput("--slow", None, f"{slow:g} is faster than --fast {fast:g}")
    if len(awaited) > NSLOTS or any(not n or len(n.encode()) > 16 for n in awaited):
        raise BadInput("--await", None, f"at most {NSLOTS} names of 1 to 16 bytes")
    start = parse_time(farm_start, "--farm-start", time.time(), durations=False) if farm_start else time.time()
    path = Path(out)
    if not path.parent.is_dir():
        raise BadInput(out, None, "its directory does not exist")
    create(path, slow=slow, fast=fast, farm_start=start, awaited=tuple(awaited))
    click.echo(f"wrote {out}: farm time {_iso(start)} now, {slow:g}x busy, {fast:g}x idle", err=True)


def _state(show: str) -> dict:
    from devices.elastic_clock import AWAITED, BUSY, IDLE, ElasticClock
    kinds = {BUSY: "busy", IDLE: "idle", AWAITED: "awaited"}
    try:
        c = ElasticClock(show)
    except FileNotFoundError:
        raise BadInput("--show", None, f"{show}: no such file") from None
    except (OSError, ValueError, BadInput) as exc:
        raise BadInput("--show", None, str(exc)) from None
    try:
        seg, now = c.segment(), c.now()
        return {"farm_time": _iso(now), "speed": c.speed, "slow": c.slow, "fast": c.fast,
                "fast_until": None if not math.isfinite(seg.limit) else _iso(seg.limit),
                "slots": [{"name": s.name, "pid": s.pid, "state": kinds[s.kind],
                           **({"until": _iso(s.value)} if s.kind == IDLE else
                              {"max_speed": s.value} if s.kind == BUSY and s.value > 0 else {}),
                           "why": s.why} for s in c.slots() if s.kind in kinds]}
    finally:
        c.close()
