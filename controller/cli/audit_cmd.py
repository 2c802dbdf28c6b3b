"""``fishfarm audit``: print the audit of operator overrides from the controller's ledger.

    fishfarm audit [--since ISO-or-duration] [--operator NAME] [--config farm.toml | --db PATH] [--json]

Every override the controller answered, accepted or refused, e-stop included (controller.records):
when, who (the authenticated user; a name only the payload claimed is shown as "NAME (claimed)"),
the command, from where, the result and the payload as received (escaped, bounded). ``--since``
takes an ISO time (``2026-06-01T06:00``, UTC unless it names an offset) or a duration back from
now (``90s``, ``30m``, ``12h``, ``7d``), now being the later of the wall clock and the ledger's
latest entry (a simulated farm's runs ahead). ``--operator`` matches the authenticated user or the
claimed name. The ledger is opened read-only: the controller may be running.
A table on a terminal, tab-separated lines otherwise, a JSON array with ``--json``.
Bad input (an unreadable --since, no ledger, a ledger without an audit) exits 2 with one line.
"""
from __future__ import annotations

import datetime as dt
import json
import math
import sqlite3
import sys
from pathlib import Path

import click

from controller.errors import BadInput
from controller.history import DURATION as _DURATION
from controller.history import UNIT_S as _UNIT_S
from controller.history import ledger_now, within_calendar

COLUMNS = ("time", "who", "command", "origin", "result", "payload")


def parse_since(text: str, now: float) -> float:
    """Unix seconds from an ISO time or a duration back from ``now``; BadInput naming --since."""
    m = _DURATION.match(text)
    if m:
        back = float(m.group(1)) * _UNIT_S[m.group(2)]
        if not math.isfinite(back):
            raise BadInput("--since", None, f"{text[:60]!r}: not a duration a float can hold")
        return within_calendar(now - back, text, "--since", span=True)
    try:
        when = dt.datetime.fromisoformat(text.strip().replace("z", "Z"))
    except ValueError:
        raise BadInput("--since", None, f"{text[:60]!r} is neither an ISO time (2026-06-01T06:00) "
                                        "nor a duration (90s, 30m, 12h, 7d)") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.UTC)
    # 9999-12-31T23:00-05:00 is in the year 10000 in UTC, where the report's dates end
    return within_calendar(when.timestamp(), text, "--since", span=False)


def _iso(t: float) -> str:
    return dt.datetime.fromtimestamp(t, dt.UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _ledger(config_path: str, db: str | None) -> str:
    if db is not None:
        return db
    from controller.config import load_config
    return load_config(config_path).store.path


def read_audit(path: str, since: float | None, operator: str | None) -> list[dict]:
    if not Path(path).is_file():
        raise BadInput(path, None, "no such ledger (has the controller run with this config?)")
    from controller.ledger_read import connect_read_only, why_unreadable
    try:
        db, _ = connect_read_only(Path(path))
    except sqlite3.OperationalError as exc:
        raise BadInput(path, None, f"cannot open the ledger: {exc}{why_unreadable(Path(path))}") from None
    except sqlite3.DatabaseError as exc:
        raise BadInput(path, None, f"not a ledger: {exc}") from None
    db.row_factory = sqlite3.Row
    try:
        sql, args = "SELECT * FROM audit WHERE 1 = 1", []
        if since is not None:
            sql, args = sql + " AND t >= ?", [since]
        if operator is not None:
            sql, args = sql + " AND (user = ? OR operator = ?)", [*args, operator, operator]
        rows = db.execute(sql + " ORDER BY id", args).fetchall()
    except sqlite3.OperationalError as exc:
        why = ("no audit in this ledger (an older schema: the controller adds it when it starts)"
               if "no such table" in str(exc) else f"cannot read the ledger: {exc}")
        raise BadInput(path, None, why) from None
    except sqlite3.DatabaseError as exc:
        raise BadInput(path, None, f"not a ledger: {exc}") from None
    finally:
        db.close()
    return [_entry(r) for r in rows]


def _entry(row: sqlite3.Row) -> dict:
    user, operator = row["user"], row["operator"]
    return {"t": _iso(row["t"]), "who": user if user else f"{operator or 'unknown'} (claimed)",
            "user": user, "operator": operator, "command": row["command"], "origin": row["origin"],
            "ok": bool(row["ok"]), "result": row["result"], "reply": row["reply"], "payload": row["payload"]}


def _cells(entry: dict) -> list[str]:
    return [entry["t"], entry["who"], entry["command"], entry["origin"], entry["result"], entry["payload"] or ""]


@click.command()
@click.option("--since", default=None, metavar="ISO|DURATION", help="from this time, or this long ago (30m, 12h, 7d).")
@click.option("--operator", default=None, metavar="NAME", help="only this user (authenticated or claimed).")
@click.option("--config", "config_path", default="config/farm.toml", show_default=True,
              help="farm config whose [store] path holds the ledger.")
@click.option("--db", default=None, metavar="PATH", help="the ledger itself (instead of --config).")
@click.option("--json", "as_json", is_flag=True, help="print a JSON array.")
def audit(since, operator, config_path, db, as_json):
    """Print the audit of operator overrides, oldest first."""
    if operator is not None and not operator.strip():     # it matched the rows with no operator at all
        raise BadInput("--operator", None, f"{operator!r} is no operator's name (1-64 characters)")
    given = click.get_current_context().get_parameter_source("config_path")
    if db is not None and given is not click.core.ParameterSource.DEFAULT:     # one was used, the other dropped
        raise BadInput("--db", None, "given with --config: name the ledger one way (--db PATH, or --config's "
                                     "[store] path)")
    path = _ledger(config_path, db)
    since_t = parse_since(since, ledger_now(path)) if since is not None else None
    entries = read_audit(path, since_t, operator)
    if as_json:
        click.echo(json.dumps(entries, ensure_ascii=False, indent=1))
    elif sys.stdout.isatty():
        from rich.console import Console
        from rich.table import Table
        from rich.text import Text
        table = Table()
        for col in COLUMNS:
            table.add_column(col, overflow="fold", no_wrap=col in ("time", "command"))
        for entry in entries:
            table.add_row(*(Text(c) for c in _cells(entry)), style=None if entry["ok"] else "red")
        Console().print(table)
    else:
        click.echo("\t".join(COLUMNS))
        for entry in entries:
            click.echo("\t".join(c.replace("\t", " ") for c in _cells(entry)))
    return 0
