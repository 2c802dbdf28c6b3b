"""``fishfarm demand``: replay a contact log through the controller's own demand filter, offline.

    fishfarm demand --events CONTACTS.csv --json OUT.json [--config farm.toml]

CONTACTS.csv: header ``t_s,tank,sensor``, one row per contact, sorted by ``t_s`` (any origin:
Unix seconds, seconds since midnight...). OUT.json: ``{"demands": [{"tank", "t_s"}], "faults":
[{"tank", "sensor", "t_s", "kind"}]}`` with kind "stuck" or "dead".

The file is read in one streaming pass with the stdlib csv reader and fed to ``DemandFilter``
exactly as the controller feeds it (``on_time`` every 5 s of log time), so memory does not grow
with the log. Without ``--config`` the tanks and sensors are whatever the log names and the
filter runs on its defaults. With ``--config`` they and ``[demand]`` come from farm.toml;
contacts of tanks or sensors the farm does not have (a sensor since removed, a typo in an old
log) are skipped, not fatal: their count and names go to stderr, the exit status stays 0.
Bad input (no file, wrong header, a non-number, times out of order, bad config) exits 2 with one
line naming the file, line and column.
"""
from __future__ import annotations

import csv
import json
import math

import click

from controller.cli.csvio import number
from controller.errors import BadInput

HEADER = ("t_s", "tank", "sensor")
TICK_S = 5.0                       # how often the controller calls on_time


def _open_events(path: str):
    # bytes that are not UTF-8 come through as lone surrogates, so the row holding them is named
    # (decoded a buffer at a time, a fault was reported at whichever line the buffer began near)
    try:
        return open(path, encoding="utf-8-sig", errors="surrogateescape", newline="")
    except FileNotFoundError:
        raise BadInput(path, None, "no such file") from None
    except IsADirectoryError:
        raise BadInput(path, None, "is a directory, expected a CSV file") from None
    except OSError as exc:
        raise BadInput(path, None, f"cannot read: {exc.strerror or exc}") from None


def _rows(path: str, repeated: list[int]):
    """(t, tank, sensor) for each contact; BadInput at the first fault. A row repeating a contact of
    the same sensor at the same instant is skipped and counted in ``repeated[0]``."""
    with _open_events(path) as fh:
        reader = csv.reader(fh)
        try:
            header = next(reader, None)
            _text(path, reader.line_num, header or [])
            if header is None:
                raise BadInput(path, None, f"empty file (expected header '{','.join(HEADER)}')")
            if tuple(c.strip() for c in header) != HEADER:
                raise BadInput(path, "header", f"expected '{','.join(HEADER)}', found '{','.join(header)}'")
            prev, at_t = -math.inf, set()
            for cells in reader:
                _text(path, reader.line_num, cells)
                if len(cells) != 3:
                    if not cells or not "".join(cells).strip():
                        continue
                    raise BadInput(path, f"line {reader.line_num}", f"{len(cells)} fields, expected 3")
                t_s, tank, sensor = cells
                t = number(t_s, path, reader.line_num, "t_s")
                if t < prev:
                    raise BadInput(path, f"line {reader.line_num}, column t_s",
                                   f"{t_s.strip()} is earlier than the row before ({prev:g}): "
                                   "rows must be sorted by time")
                tank = _name(path, reader.line_num, "tank", tank)
                sensor = _name(path, reader.line_num, "sensor", sensor)
                if t != prev:
                    at_t = set()
                # one sensor rises once at an instant: a row given twice counted twice (a tester's
                # doubled log raised 0.67 -> 21.8 false demands a tank-day). Counted once, and said:
                # a log written to the millisecond may also round two of a burst's contacts together
                if (tank, sensor) in at_t:
                    repeated[0] += 1
                    continue
                at_t.add((tank, sensor))
                prev = t
                yield t, tank, sensor
        except csv.Error as exc:
            raise BadInput(path, f"line {reader.line_num}", f"not CSV: {exc}") from None


def _text(path: str, line: int, cells: list[str]) -> None:
    """BadInput naming the line if a cell is not UTF-8 (its bytes came through as surrogates)."""
    for cell in cells:
        if not cell.isascii():
            try:
                cell.encode("utf-8")
            except UnicodeEncodeError:
                raise BadInput(path, f"line {line}", "not UTF-8 text (expected a CSV file)") from None


def _name(path: str, line: int, column: str, name: str) -> str:
    """A tank's or sensor's name, stripped; BadInput if empty or unprintable (a NUL or an escape
    went through to the JSON and to a terminal)."""
    name = name.strip()
    if not name:
        raise BadInput(path, f"line {line}, column {column}", "empty")
    if not name.isprintable():
        bad = next(ch for ch in name if not ch.isprintable())
        raise BadInput(path, f"line {line}, column {column}", f"unprintable character {bad!r} in {name!r}")
    return name


def replay(path: str, params=None, tanks: dict[str, list[str]] | None = None):
    """Run the log through a fresh DemandFilter; returns (events, filter, rows that repeated a
    contact and were counted once)."""
    from controller.demand import DemandFilter
    filt = DemandFilter(params, tanks)
    on_contact, on_time = filt.on_contact, filt.on_time
    events: list = []
    tick, last = -math.inf, None
    repeated = [0]
    for t, tank, sensor in _rows(path, repeated):
        if t >= tick:
            events.extend(on_time(t))
            tick = t + TICK_S
        out = on_contact(t, tank, sensor)
        if out:
            events.extend(out)
        last = t
    if last is not None:
        events.extend(on_time(last))
    return events, filt, repeated[0]


def to_json(events) -> dict:
    from controller.demand import Demand, SensorFault
    return {"demands": [{"tank": e.tank, "t_s": e.t} for e in events if isinstance(e, Demand)],
            "faults": [{"tank": e.tank, "sensor": e.sensor, "t_s": e.t, "kind": e.kind}
                       for e in events if isinstance(e, SensorFault)]}


def _farm(config: str):
    from controller.config import load_config, validate_section
    from controller.demand import DemandParams
    cfg = load_config(config)
    params = validate_section(DemandParams, cfg.demand, cfg.path, "demand")
    return params, {t.id: list(t.sensors) for t in cfg.tanks}


@click.command("demand")
@click.option("--events", "events_path", required=True, metavar="CONTACTS.csv",
              help="contact log: header t_s,tank,sensor, sorted by time")
@click.option("--json", "json_path", required=True, metavar="OUT.json", help="demands and sensor faults")
@click.option("--config", "config", default=None, metavar="FARM.toml",
              help="take tanks, sensors and [demand] parameters from the farm's config")
def demand(events_path: str, json_path: str, config: str | None) -> None:
    """Replay a contact log through the demand filter; write the demands and sensor faults."""
    from controller.cli.output_paths import check_outputs
    check_outputs({"--json": json_path}, [events_path, config])
    params, tanks = _farm(config) if config else (None, None)
    events, filt, repeated = replay(events_path, params, tanks)
    out = to_json(events)
    from controller.atomic_files import write_text_atomically
    write_text_atomically(json_path, json.dumps(out, indent=1) + "\n")
    if repeated:
        click.echo(f"fishfarm demand: {repeated} rows repeated a contact of the same sensor at the same "
                   "instant: each counted once", err=True)
    if filt.ignored:
        names = ", ".join(f"{t}/{s}" for t, s in sorted(filt.unknown)[:10])
        more = "" if len(filt.unknown) <= 10 else f" and {len(filt.unknown) - 10} more"
        click.echo(f"fishfarm demand: skipped {filt.ignored} contacts of tanks/sensors not in {config}: "
                   f"{names}{more}", err=True)
