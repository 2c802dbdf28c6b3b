"""``fishfarm history --tank T --what surveys|fish|rations|stock|feeds [--since ISO|DURATION]
[--until ISO] [--csv OUT.csv] [--config farm.toml]``

A tank's history from the ledger (controller/history.py), as CSV — to ``--csv`` or stdout — with
the units in the headers' names. The same rows the controller serves on
``farm/{site}/history/{what}/{tank}``; a ``--since`` duration goes back from the later of the wall
clock and the ledger's latest entry (the ledger holds farm time).
Reads the ledger only. Bad input exits 2 with one line.
"""
from __future__ import annotations

import csv
import sys
from pathlib import Path

import click

from controller.errors import BadInput


@click.command()
@click.option("--tank", "tank_id", required=True, help="the tank's id")
@click.option("--what", required=True, type=click.Choice(["surveys", "fish", "rations", "stock", "feeds"]))
@click.option("--since", default=None, metavar="ISO|DURATION", help="from this time, or this long ago (30d)")
@click.option("--until", default=None, metavar="ISO", help="up to this time")
@click.option("--csv", "csv_path", default=None, metavar="OUT.csv", help="write here (default: stdout)")
@click.option("--config", "config_path", default="config/farm.toml", show_default=True, metavar="farm.toml")
def history(tank_id, what, since, until, csv_path, config_path) -> None:
    """A tank's surveys, fish, rations, stock events or feeds, as CSV."""
    from controller.cli.output_paths import check_outputs
    from controller.config import load_config
    from controller.history import history as rows_of
    from controller.history import ledger_now, parse_time
    from controller.store import Store
    cfg = load_config(config_path)
    check_outputs({"--csv": csv_path}, [config_path, cfg.store.path])
    if tank_id not in {t.id for t in cfg.tanks}:
        raise BadInput(config_path, "--tank", f"no tank {tank_id!r} (tanks: {', '.join(t.id for t in cfg.tanks)})")
    now = ledger_now(cfg.store.path)
    start = parse_time(since, "--since", now, durations=True) if since else None
    end = parse_time(until, "--until", now, durations=False) if until else None
    if not Path(cfg.store.path).exists():
        raise BadInput(cfg.store.path, None, "no ledger there (the controller has not run with this config)")
    store = Store.reader(cfg.store.path)
    try:
        columns, rows, truncated = rows_of(store, what, tank_id, start, end)
    finally:
        store.close()

    def write(out) -> None:
        writer = csv.writer(out)
        writer.writerow(columns)
        writer.writerows(rows)
    if not csv_path:
        write(sys.stdout)
    else:
        from controller.atomic_files import write_file_atomically
        write_file_atomically(csv_path, write)
        more = " (the first of more: narrow the range)" if truncated else ""
        click.echo(f"{len(rows)} rows{more}: {csv_path}", err=True)
