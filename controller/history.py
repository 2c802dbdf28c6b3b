"""A tank's history from the ledger, over a time range: for the Zenoh queryable
``farm/{site}/history/{what}/{tank}?since=...;until=...`` and for ``fishfarm history --csv``.

``what``: ``surveys`` (one row a survey: its summary), ``fish`` (every fish every survey counted),
``rations`` (one row a farm day: grams, pellet, what it rested on), ``stock`` (mortality, harvests
and transfers in or out), ``feeds`` (every feed: intent time, aim, grams measured, outcome).
``since``/``until``: an ISO time (2026-06-01T06:00, UTC unless it says) or Unix seconds; ``since``
also a duration back from now (30m, 12h, 7d); none of them before 2000 but 0. Rows come oldest
first, the queryable's at most ``MAX_ROWS``; the command line's all of them.
"""
from __future__ import annotations

import datetime as dt
import itertools
import math
import re
import time

from controller.errors import BadInput

DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(s|m|h|d|w)\s*$", re.ASCII)
# Unix seconds as written in ASCII (float() also reads "١٢" and "1_000"); eight digits alone are
# ISO's basic date (20261204), not seconds of 1970
SECONDS = re.compile(r"^\d+(\.\d+)?$", re.ASCII)
FIRST_S = 946_684_800.0        # 2000-01-01: no ledger of ours holds anything older (2026120 was a date's typo)
BASIC_DATE = re.compile(r"^\d{8}$", re.ASCII)
UNIT_S = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 7 * 86400}
# the calendar's ends, years 1 to 9999: no date is written for a time outside them (strftime,
# fromtimestamp), and 1e20 or 99999999999999999w took the refusal's own message down with it
CALENDAR_S = (-62_135_596_800.0, 253_402_300_800.0)
MAX_ROWS = 100_000
COLUMNS = {
    "surveys": ("time", "survey", "species", "count", "mean_weight_g", "sd_weight_g", "mean_length_cm",
                "cv_pct", "source"),
    "fish": ("time", "survey", "length_cm", "weight_g", "score"),
    "rations": ("time", "date", "grams", "pellet_mm", "basis"),
    "stock": ("time", "kind", "count", "from_tank", "to_tank", "who", "reason", "event"),
    "feeds": ("time", "feed", "date", "target_g", "grams", "phase", "source", "note"),
}
_SQL = {
    "surveys": ("SELECT t, id, species, count, mean_weight_g, sd_weight_g, mean_length_cm, cv_pct, source "
                "FROM survey WHERE tank = :tank AND t >= :since AND t <= :until ORDER BY t, id"),
    "fish": ("SELECT s.t, s.id, f.length_cm, f.weight_g, f.score FROM survey_fish f JOIN survey s "
             "ON s.id = f.survey WHERE s.tank = :tank AND s.t >= :since AND s.t <= :until ORDER BY s.t, s.id, f.rowid"),
    "rations": ("SELECT t, date, grams, pellet_mm, source FROM ration WHERE tank = :tank AND t >= :since "
                "AND t <= :until ORDER BY date"),
    "stock": ("SELECT t, kind, count, tank, to_tank, who, reason, id FROM stock_event WHERE (tank = :tank "
              "OR to_tank = :tank) AND t >= :since AND t <= :until ORDER BY t, id"),
    "feeds": ("SELECT t_intent, id, date, target_g, grams, phase, source, note FROM feed WHERE tank = :tank "
              "AND t_intent >= :since AND t_intent <= :until ORDER BY seq"),
}
WHAT = tuple(COLUMNS)


def parse_time(text, name: str, now: float, *, durations: bool) -> float:
    """Unix seconds from ISO, Unix seconds or (``durations``) a span back from ``now``."""
    if isinstance(text, bool) or text is None:      # JSON's true and null, not Python's True and None
        forms = "ISO, Unix seconds or a span" if durations else "ISO or Unix seconds"
        said = "null" if text is None else str(text).lower()
        raise BadInput(name, None, f"{said}: not a time ({forms}); leave {name} out for no bound")
    if isinstance(text, int | float):      # a JSON number: seconds, however written
        try:
            value, text, span = float(text), repr(text), False
        except OverflowError:           # a JSON integer of 400 digits (its repr may not be written either)
            raise BadInput(name, None, "an integer too big for a float: not a time") from None
    else:
        text = str(text).strip()
        span = bool(durations and DURATION.match(text))
        value = _read_time(text, name, now, durations)
    if not math.isfinite(value):
        raise BadInput(name, None, f"{text[:60]!r}: not a time a float can hold")
    _refuse_before_2000(value, text, name, span=span, durations=durations)
    within_calendar(value, text, name, span=span)
    return value


def ledger_now(path) -> float:
    """"Now" for a duration the offline commands measure back: the later of the wall clock and the
    ledger's latest entry. A simulated farm's ledger holds farm time, hours or days ahead of the wall
    at --speed 60, and "1h" back from the wall clock took in everything."""
    from controller.store import ledger_time
    return max(time.time(), ledger_time(path) or -math.inf)


def within_calendar(value: float, text: str, name: str, *, span: bool) -> float:
    """``value`` when a date can be written for it, else BadInput naming ``name``."""
    if not CALENDAR_S[0] <= value < CALENDAR_S[1]:        # NaN too
        if span:
            raise BadInput(name, None, f"{text[:60]!r} reaches back before year 1; leave {name} out for everything")
        where = "before year 1" if value < CALENDAR_S[0] else "after the year 9999"
        raise BadInput(name, None, f"{text[:60]!r} is {where}: beyond the calendar")
    return value


def _read_time(text: str, name: str, now: float, durations: bool) -> float:
    if SECONDS.match(text) and not BASIC_DATE.match(text):
        # a number too big for a float (310 digits and more) is not read as an ISO date either:
        # fromisoformat took '1111...' for 1111-11-11 and every row came back
        return float(text)
    m = DURATION.match(text) if durations else None
    if m:
        return now - float(m.group(1)) * UNIT_S[m.group(2)]
    try:
        when = dt.datetime.fromisoformat(text.replace("z", "Z"))
    except ValueError:
        spans = ", a duration (30m, 12h, 7d)" if durations else ""
        raise BadInput(name, None, f"{text[:60]!r} is not an ISO time (2026-06-01T06:00), "
                                   f"Unix seconds{spans}") from None
    return (when if when.tzinfo else when.replace(tzinfo=dt.UTC)).timestamp()


def _refuse_before_2000(value: float, text: str, name: str, *, span: bool, durations: bool) -> None:
    """Every form, not only seconds: 1999-12-31 or 99999999d also brought back every row."""
    if span and value < FIRST_S:
        raise BadInput(name, None, f"{text[:60]!r} reaches back before 2000: no ledger holds anything that "
                                   f"old; leave {name} out for every row")
    if value < 0 or 0 < value < FIRST_S:        # 0 is the beginning, asked for on purpose
        forms = "an ISO time, Unix seconds or a duration" if durations else "an ISO time or Unix seconds"
        when = iso(value) if value >= CALENDAR_S[0] else "a time"
        raise BadInput(name, None, f"{text[:60]!r}: {when} is before 2000 (a date's typo?): {forms}")


def iso(t: float) -> str:
    return dt.datetime.fromtimestamp(t, dt.UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


# A row's time is written to the millisecond, and a bound takes in the rows its own millisecond
# holds: written to the second, a row's printed time given back as --until left the row out (the
# ledger keeps the time to the microsecond), and rows of one second could not be put in order.
HALF_MS = 0.0005


def row_time(t: float) -> str:
    return dt.datetime.fromtimestamp(round(t, 3), dt.UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def history(store, what: str, tank: str, since: float | None = None, until: float | None = None):
    """(columns, rows, truncated): the rows oldest first, ``time`` as ISO, at most ``MAX_ROWS`` (a
    queryable's reply is one message)."""
    columns, rows = stream(store, what, tank, since, until, limit=MAX_ROWS + 1)
    try:
        kept = list(itertools.islice(rows, MAX_ROWS + 1))
    finally:
        rows.close()
    return columns, kept[:MAX_ROWS], len(kept) > MAX_ROWS


def stream(store, what: str, tank: str, since: float | None = None, until: float | None = None, *,
           limit: int | None = None):
    """(columns, rows): every row oldest first, ``time`` as ISO, read from the ledger as they are
    consumed (``fishfarm history`` writes 150,000 fish in the memory of one); ``rows.close()``
    ends the read early."""
    if what not in COLUMNS:
        raise BadInput("what", None, f"{what!r} is not one of {', '.join(WHAT)}")
    if since is not None and until is not None and since > until:
        raise BadInput("since", None, f"{iso(since)} is after until ({iso(until)}): no time lies between")
    args = {"tank": tank, "since": -math.inf if since is None else since - HALF_MS,
            "until": math.inf if until is None else until + HALF_MS}
    # a LIMIT lets SQLite keep only that many rows in its sort, not the tank's every fish
    cur = store.db.execute(_SQL[what] + ("" if limit is None else f" LIMIT {int(limit)}"), args)

    def rows():
        try:
            for r in cur:
                yield [row_time(r[0]), *r[1:]]
        finally:
            cur.close()
    return COLUMNS[what], rows()


def query_reply(store, cfg, key: str, params: dict, now: float) -> dict:
    """The queryable's answer to ``history/{what}/{tank}`` with its selector's parameters."""
    parts = key.split("/")
    if len(parts) != 3 or parts[0] != "history":
        return {"ok": False, "error": f"ask history/{{{'|'.join(WHAT)}}}/{{tank}}, not {key!r}"}
    what, tank = parts[1], parts[2]
    tanks = [t.id for t in cfg.tanks]
    if tank not in tanks:
        return {"ok": False, "error": f"no tank {tank!r} (tanks: {', '.join(tanks)})"}
    glued = [k for k, v in params.items() if isinstance(v, str) and "&" in v and "=" in v]
    if glued:           # a URL's habit: Zenoh took "7d&until=1d" for the value of since
        return {"ok": False, "error": f"{glued[0]}: {params[glued[0]]!r}: a selector's parameters are "
                                      "separated by ';', not '&' (since=7d;until=2026-07-01)"}
    unknown = sorted(set(params) - {"since", "until"})
    if unknown:
        return {"ok": False, "error": f"unknown parameter {unknown[0]!r}: since, until"}
    try:
        since = parse_time(params["since"], "since", now, durations=True) if "since" in params else None
        until = parse_time(params["until"], "until", now, durations=False) if "until" in params else None
        columns, rows, truncated = history(store, what, tank, since, until)
    except BadInput as exc:
        return {"ok": False, "error": str(exc)}
    return {"ok": True, "what": what, "tank": tank, "columns": list(columns), "rows": rows, "truncated": truncated}
