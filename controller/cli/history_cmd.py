"""``fishfarm history --tank T --what surveys|fish|rations|stock|feeds [--since ISO|DURATION]
[--until ISO] [--csv OUT.csv] [--config farm.toml]``

A tank's history from the ledger (controller/history.py), as CSV — to ``--csv`` or stdout — with
the units in the headers' names; a text cell a spreadsheet would take for a formula (``=``, ``+``,
``-``, ``@``, tab, CR first) begins with ``'``. The same rows the controller serves on
``farm/{site}/history/{what}/{tank}``, but every one of them: they are streamed from the ledger to
the file (the queryable's reply stops at 100,000). A ``--since`` duration goes back from the later
of the wall clock and the ledger's latest entry (the ledger holds farm time).
Reads the ledger only. Bad input exits 2 with one line.
"""
from __future__ import annotations

import csv
import os
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
    from controller.cli.csvio import text_cell
    from controller.cli.output_paths import check_outputs
    from controller.config import load_config
    from controller.history import ledger_now, parse_time, stream
    from controller.store import Store
    cfg = load_config(config_path)
    from controller.farm_setup import check_species_file
    check_species_file(cfg)                    # as `run` refuses it: a misspelt species is another fish
    check_outputs({"--csv": csv_path}, [config_path, cfg.store.path])
    configured = tank_id in {t.id for t in cfg.tanks}
    now = ledger_now(cfg.store.path)
    start = parse_time(since, "--since", now, durations=True) if since is not None else None
    end = parse_time(until, "--until", now, durations=False) if until is not None else None
    if not Path(cfg.store.path).exists():
        if not configured:
            raise BadInput(config_path, "--tank", f"no tank {tank_id!r} (tanks: {', '.join(t.id for t in cfg.tanks)})")
        raise BadInput(cfg.store.path, None, "no ledger there (the controller has not run with this config)")
    store = Store.reader(cfg.store.path, cfg.surveys.min_weighed_fish)
    if not configured:
        # a tank taken out of the config (or renamed) keeps its rows: they are read as recorded
        if not _in_ledger(store, tank_id):
            store.close()
            raise BadInput(config_path, "--tank", f"no tank {tank_id!r} (tanks: {', '.join(t.id for t in cfg.tanks)}; "
                                                  "none of that id in the ledger either)")
        click.echo(f"tank {tank_id} is not in {config_path}: its ledger rows as recorded", err=True)
    written, rows = 0, None
    try:
        columns, rows = stream(store, what, tank_id, start, end)

        def write(out) -> None:
            nonlocal written
            writer = csv.writer(out)
            writer.writerow(columns)
            for row in rows:
                writer.writerow([text_cell(c) for c in row])      # an operator's name or reason: text
                written += 1
        if not csv_path:
            _to_stdout(write)
        else:
            from controller.atomic_files import write_file_atomically
            write_file_atomically(csv_path, write)
            click.echo(f"{written} rows: {csv_path}", err=True)
    finally:
        if rows is not None:         # the read ends before the ledger closes (`| head` left it midway)
            rows.close()
        store.close()


def _to_stdout(write) -> None:
    try:
        write(sys.stdout)
        sys.stdout.flush()
    except BrokenPipeError:         # `... | head`: the reader left, nothing more to say
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())


def _in_ledger(store, tank_id: str) -> bool:
    """Whether the ledger holds any row of ``tank_id`` (a tank since taken out of the config)."""
    return any(store.db.execute(sql, (tank_id,) * sql.count("?")).fetchone() for sql in (
        "SELECT 1 FROM survey WHERE tank = ? LIMIT 1", "SELECT 1 FROM feed WHERE tank = ? LIMIT 1",
        "SELECT 1 FROM ration WHERE tank = ? LIMIT 1",
        "SELECT 1 FROM stock_event WHERE tank = ? OR to_tank = ? LIMIT 1"))
