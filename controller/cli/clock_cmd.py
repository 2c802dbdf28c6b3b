"""``fishfarm clock``: make an elastic clock file for a simulated farm, or show one.

    fishfarm clock --out FILE --slow X --fast Y [--farm-start ISO|UNIX] [--await NAME ...]
    fishfarm clock --show FILE

The file (devices/elastic_clock.py) is what ``fishfarm sim --clock FILE`` and ``fishfarm run
--clock FILE`` share: farm time runs at ``--slow`` while any of them is busy and at ``--fast``
while all are idle. ``--await sim --await controller`` reserves their slots before they start, so
the clock stays slow until each has said what it needs (as hil_tests/farm.py does). ``--show``
prints the current segment and every slot (``dead``: its process is gone) as one JSON object.
Bad input exits 2 with one line.
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
    from controller.atomic_files import replace_atomically
    from controller.history import parse_time
    from devices.clock_file import SLOTS, farm_range_fault, layout, speed_fault
    for name, value in (("--slow", slow), ("--fast", fast)):
        if value is None:
            raise BadInput(name, None, "required with --out")
        if (fault := speed_fault(value)) is not None:    # (1e300 was taken, and --show overflowed)
            raise BadInput(name, None, fault)
    if slow > fast:
        raise BadInput("--slow", None, f"{slow:g} is faster than --fast {fast:g}")
    # a name nobody claims, or one given twice, held the clock slow for good
    for name in awaited:
        if name not in SLOTS:
            raise BadInput("--await", None, f"{name!r}: no process claims it (the farm's are {', '.join(SLOTS)})")
    if len(set(awaited)) != len(awaited):
        raise BadInput("--await", None, f"{' '.join(awaited)}: a name given twice")
    start = parse_time(farm_start, "--farm-start", time.time(), durations=False) if farm_start else time.time()
    if (fault := farm_range_fault(start)) is not None:   # (0 was taken, 9999-12-31 crashed later)
        raise BadInput("--farm-start", None, f"{farm_start}: {fault}")
    _check_out(out)
    data = layout(slow=slow, fast=fast, farm_start=start, awaited=tuple(awaited), wall=time.time())
    replace_atomically(out, lambda tmp: Path(tmp).write_bytes(data))
    click.echo(f"wrote {out}: farm time {_iso(start)} now, {slow:g}x busy, {fast:g}x idle", err=True)


def _check_out(out: str) -> None:
    """The project's output rules (a directory refused by name; a device or a FIFO written into,
    never replaced), and a file already there replaced only if it is a clock file no live process
    is on: renaming over any file put a clock where a config had been."""
    from controller.atomic_files import special
    from controller.cli.output_paths import check_outputs
    from devices.clock_file import BUSY, IDLE, is_clock_file, process_alive
    check_outputs({"--out": out}, [])
    path = Path(out)
    if special(path) or not path.exists():
        return
    if not is_clock_file(path):
        raise BadInput(out, "--out", "exists and is not a clock file: not replaced (remove it first)")
    live = [s for s in _slots_of(path) if s.kind in (BUSY, IDLE) and s.pid > 0 and process_alive(s.pid)]
    if live:
        raise BadInput(out, "--out", f"a farm runs on this clock ({live[0].name!r}: pid {live[0].pid}): "
                                     "not replaced")


def _slots_of(path: Path) -> list:
    from devices.clock_file import HEAD, NSLOTS, SIZE, SLOT, decode_slot
    data = path.read_bytes()
    if len(data) < SIZE:
        return []
    return [decode_slot(SLOT.unpack_from(data, HEAD.size + i * SLOT.size)) for i in range(NSLOTS)]


def _state(show: str) -> dict:
    from devices.elastic_clock import AWAITED, BUSY, IDLE, ElasticClock, process_alive
    kinds = {BUSY: "busy", IDLE: "idle", AWAITED: "awaited"}
    try:
        c = ElasticClock(show)
    except FileNotFoundError:
        raise BadInput("--show", None, f"{show}: no such file") from None
    except (OSError, ValueError, BadInput) as exc:
        raise BadInput("--show", None, str(exc)) from None
    try:
        seg, now = c.segment(), c.now()
        return {"farm_time": _iso(now), "speed": c.speed, "slow": c.slow, "fast": c.fast, "lease_s": c.lease_s,
                # (a slow segment's limit is where its lease lapses: no fast part)
                "fast_until": _iso(seg.limit) if math.isfinite(seg.limit) and seg.speed >= c.fast else None,
                "segment": {"wall0": seg.wall0, "farm0": _iso(seg.farm0), "speed": seg.speed,
                            "limit": None if not math.isfinite(seg.limit) else _iso(seg.limit),
                            "after": seg.after},
                "slots": [{"name": s.name, "pid": s.pid, "state": kinds[s.kind],
                           **({"until": _iso(s.value)} if s.kind == IDLE else
                              {"max_speed": s.value} if s.kind == BUSY and s.value > 0 else {}),
                           # a dead process's word holds the clock slow, whatever it says
                           **({"dead": True} if s.kind != AWAITED and not process_alive(s.pid) else {}),
                           "why": s.why} for s in c.slots() if s.kind in kinds]}
    finally:
        c.close()
