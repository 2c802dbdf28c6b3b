"""The config a controller starts with, against the ledger it carries on: what the two cannot both
be is refused (exit 2 naming the key), what changed since the last start is said, once, in the log.

A farm edits farm.toml between restarts; the ledger keeps what happened under the old one:
- a tank's ``stock`` is its count when the ledger began, its stock events counted from there. One
  lowered below what the events took out (500 where a harvest took 600) made the stock negative:
  ``status`` failed for the whole farm, the SCADA froze, housekeeping crashed every farm minute;
- ``utc_offset_h`` moved west far enough to put today before the ledger's last farm day: the day's
  rations started again from nothing and the fish that had been fed were fed again;
- the rest is the farm's to change, but it changes the past's reading: today's count folding in
  the events a second time (the config's stock set to today's count), surveys reclassified by
  ``min_weighed_fish``, another species over a tank's surveys, the SCADA's tank blocks and alarm
  slots moved by tanks or devices added, removed or reordered. Each is logged at start
  (``config_seen`` holds what the last start ran with; MIGRATION_10).
"""
from __future__ import annotations

import json
import logging
import sqlite3

from controller.errors import BadInput
from controller.production import fish_out
from devices.clock import farm_date

log = logging.getLogger("fishfarm.config")

MIGRATION_10 = """
    CREATE TABLE config_seen (
        key    TEXT PRIMARY KEY,
        value  TEXT NOT NULL,
        t      REAL NOT NULL
    );
"""
"""9 -> 10: what the last start's config said of the things the ledger's past is read by."""


def check_against_ledger(cfg, store, now: float) -> None:
    """BadInput for a config the ledger's events and days rule out; then the changes logged and the
    config kept as the last seen (after the checks: a refused config is not remembered)."""
    events = [dict(e) for e in store.stock_events()]
    for i, tank in enumerate(cfg.tanks):
        _check_stock(cfg, i, tank, events)
    _check_day(cfg, store, now)
    said = seen(cfg)
    before = {row[0]: json.loads(row[1]) for row in store.db.execute("SELECT key, value FROM config_seen")}
    for line in changes(before, said):
        log.warning("config: %s", line)
    try:
        with store.transaction() as db:
            db.executemany("INSERT OR REPLACE INTO config_seen (key, value, t) VALUES (?, ?, ?)",
                           [(k, json.dumps(v), now) for k, v in said.items()])
    except sqlite3.OperationalError as exc:
        # a full disk at start is the ledger alarm's to tell (the controller runs on, nothing fed
        # until it can write): this start's config is compared again at the next one
        log.warning("config: not remembered for the next start: the ledger cannot be written (%s)", exc)


def _check_stock(cfg, i: int, tank, events: list[dict]) -> None:
    stock, lowest = tank.stock, None
    for e in sorted(events, key=lambda e: (e["t"], e["id"])):
        stock -= fish_out(e, tank.id)
        if stock < 0 and lowest is None:
            lowest = (stock, e)
    if lowest is not None:
        n, e = lowest
        raise BadInput(cfg.path, f"tanks.{i}.stock",
                       f"{tank.stock} fish, but the ledger's stock events take tank {tank.id!r} to {n} at its "
                       f"{e['kind']} of {farm_date(e['t'], cfg.utc_offset_h)} ({e['count']} fish): `stock` is the "
                       f"count the ledger began with, its events counted from it, not today's")


def _check_day(cfg, store, now: float) -> None:
    today = farm_date(now, cfg.utc_offset_h)
    last = store.db.execute("SELECT MAX(d) FROM (SELECT MAX(date) AS d FROM ration "
                            "UNION ALL SELECT MAX(date) FROM feed)").fetchone()[0]
    if last is not None and last > today:
        raise BadInput(cfg.path, "utc_offset_h",
                       f"{cfg.utc_offset_h:g} h makes today {today}, before the ledger's last farm day {last}: "
                       f"that day's rations would start again and its fish be fed again; start once {last} "
                       "has begun in the new zone, or keep the old offset until then")


def seen(cfg) -> dict:
    """What the ledger's past is read by, as the config says it now (JSON-able values)."""
    out = {"tanks": [t.id for t in cfg.tanks], "devices": list(cfg.devices),     # the alarm slots' order
           "utc_offset_h": cfg.utc_offset_h, "min_weighed_fish": cfg.surveys.min_weighed_fish}
    for t in cfg.tanks:
        out[f"tank.{t.id}"] = {"stock": t.stock, "species": t.species}
    return out


def changes(before: dict, now: dict) -> list[str]:
    """One line per change that reads the past anew or moves the SCADA's map (empty the first time)."""
    if not before:
        return []
    lines = []
    if before.get("tanks") is not None and before["tanks"] != now["tanks"]:
        lines.append(f"tanks {before['tanks']} -> {now['tanks']}: the SCADA's tank blocks are in this order "
                     "(its layout_crc changed); a tank's ledger rows stay under its id")
    if before.get("devices") is not None and before["devices"] != now["devices"]:
        lines.append(f"devices {before['devices']} -> {now['devices']}: the SCADA's alarm slots moved")
    for key, what in (("utc_offset_h", "the farm day's start"), ("min_weighed_fish", "which surveys weigh a tank")):
        if key in before and before[key] != now[key]:
            lines.append(f"{key} {before[key]:g} -> {now[key]:g}: {what} changed, for the past's rows too")
    for key, value in now.items():
        old = before.get(key)
        if not key.startswith("tank.") or old is None:
            continue
        tank = key[5:]
        if old["stock"] != value["stock"]:
            lines.append(f"tank {tank}: stock {old['stock']} -> {value['stock']}: the count the ledger began with, "
                         "its stock events counted from it (not today's count: they would count twice)")
        if old["species"] != value["species"]:
            lines.append(f"tank {tank}: species {old['species']} -> {value['species']}: its surveys so far "
                         f"were of {old['species']}")
    return lines
