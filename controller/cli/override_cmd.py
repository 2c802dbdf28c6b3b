"""``fishfarm override`` and ``fishfarm status``: an operator's tools, Zenoh clients of the controller.

Exit status: 0 the controller accepted, 1 it refused (``"ok": false``), 2 bad input or no
controller reachable (one line on stderr).
"""
from __future__ import annotations

import getpass
import json
import math
import os
import re
import uuid

import click

from controller.cli.params import Finite
from controller.console import survey_line
from controller.errors import BadInput
from controller.text import printable

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"  # the demo config's listener (DESIGN.md)
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_COMMAND = re.compile(r"^[a-z][a-z0-9_-]{0,63}$")
_SITE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_RESERVED = {"operator": "--operator", "reason": "--reason"}
# identifiers, whatever they look like: a tank may be called 12, a feed 0123
_STRINGS = {"tank", "to", "id", "source", "kind", "request"}


def _connection_options(f):
    """--connect/--user/--password/--ca/--site/--timeout, shared by both commands."""
    for option in reversed([
        click.option("--connect", default=DEFAULT_CONNECT, show_default=True, metavar="tcp/HOST:PORT",
                     help="Zenoh endpoint of the controller (or its router)."),
        click.option("--user", default=None, help="Zenoh user name (deployments with authentication)."),
        click.option("--password", default=None, help="Zenoh password."),
        click.option("--ca", default=None, type=click.Path(exists=True, dir_okay=False),
                     help="certificate (PEM) that signed the controller's, for a tls/HOST:PORT endpoint."),
        click.option("--site", default="demo", show_default=True, help="farm site, as in farm.toml."),
        click.option("--timeout", "timeout_s", default=2.0, show_default=True, type=Finite(0.1, 60),
                     help="seconds to wait for the connection and for the reply."),
    ]):
        f = option(f)
    return f


def parse_args(args: tuple[str, ...] | list[str]) -> dict:
    """``key=value`` words into a JSON object: values that read as numbers become numbers,
    ``true``/``false`` booleans, the rest strings; ``tank`` and ``id`` are always strings (``tank=12``)."""
    fields: dict = {}
    for word in args:
        key, eq, text = word.partition("=")
        if not eq or not _NAME.match(key):
            raise BadInput("ARGS", word, "expected key=value with a plain key (letters, digits, _)")
        if key in _RESERVED:
            raise BadInput("ARGS", word, f"use {_RESERVED[key]} for {key}")
        if key in fields:
            raise BadInput("ARGS", word, f"{key} given twice")
        fields[key] = text if key in _STRINGS else _value(text)
    return fields


def _value(text: str):
    """A boolean or a number if the whole text is one (finite), else the text itself: tank=T1 stays
    a string, and so does anything the controller should refuse as one (grams=abc, on=yes)."""
    if text in ("true", "false"):
        return text == "true"
    for kind in (int, float):
        try:
            number = kind(text)
        except ValueError:
            continue
        if math.isfinite(number) and text.strip() == text and "_" not in text:
            return number
    return text


def _login_name() -> str:
    """$USER, else the login name from the password database (containers often lack $USER)."""
    try:
        return os.environ.get("USER") or getpass.getuser()
    except (KeyError, OSError):
        return "unknown"


def _check(site: str, connect: str) -> None:
    if not _SITE.match(site):
        raise BadInput("--site", site, "letters, digits, _ and - only")
    if not re.match(r"^[a-z0-9-]+/\S+$", connect):
        raise BadInput("--connect", connect, "expected an endpoint like tcp/127.0.0.1:7447")


def _ask(connect, user, password, site, timeout_s, suffix, payload, ca=None, again="") -> dict:
    """One get through a fresh client session; the first reply, or BadInput if nobody answers.
    An override with --user goes to ``override/COMMAND/by/USER``: the key the deployment's access
    control lets only USER query, so the controller knows who sent it (controller/identity.py)."""
    from controller.bus import Bus, BusUnreachable  # Zenoh only for the commands that need it
    from controller.identity import BY, USER

    _check(site, connect)
    if user is not None and not USER.match(user):
        raise BadInput("--user", user, "letters, digits, _ . - only")
    if user is not None and suffix.startswith("override/"):
        suffix = f"{suffix}/{BY}/{user}"
    try:
        bus = Bus.client(connect, site=site, user=user, password=password, timeout_s=timeout_s, ca=ca)
    except BusUnreachable as exc:
        raise BadInput("--connect", None, str(exc)) from None
    try:
        replies = bus.query(suffix, payload, timeout_s=timeout_s)
        # access control (a deployment's logins) drops a refused query silently: tell it from an
        # absent controller by asking for status, which every role may. A controller that answered
        # status but not in time is as likely (busy, a slow link): both are said, and the id
        refused = (not replies and user is not None and suffix != "status"
                   and bool(bus.query("status", timeout_s=timeout_s)))
    finally:
        bus.close()
    if refused:
        raise BadInput(f"farm/{site}/{suffix}", None,
                       f"no reply within {timeout_s:g} s while status answers: user {user!r} may not send this "
                       f"(access control), or the controller answered too late{again}")
    if not replies:
        raise BadInput(f"farm/{site}/{suffix}", None,
                       f"no reply within {timeout_s:g} s (no controller serving this site, or not permitted)"
                       + again)
    return replies[0]


def estop_fields(args) -> dict:
    """An e-stop's ARGS, read as far as they can be: what cannot be read is said on stderr and left
    out, never a reason not to send it (DESIGN.md: an emergency action is never refused for a
    missing detail; ``fishfarm override estop now`` exited 2 and stopped nothing)."""
    fields: dict = {}
    for word in args:
        try:
            for k, v in parse_args([word]).items():
                if k in fields:
                    raise BadInput(word, None, f"{k} given more than once (the first is sent)")
                fields[k] = v
        except BadInput as exc:
            click.echo(f"fishfarm override: {exc}: left out, the e-stop is sent all the same", err=True)
    return fields


@click.command(context_settings={"ignore_unknown_options": True})
@click.argument("command")
@click.argument("args", nargs=-1)
@click.option("--operator", default=_login_name, show_default="$USER",
              help="who gives the command (logged by the controller).")
@click.option("--reason", default=None, help="why (logged by the controller).")
@_connection_options
def override(command, args, operator, reason, connect, user, password, ca, site, timeout_s):
    """Send an operator command (estop, feed, pause, ...) to the controller.

    ARGS are key=value fields of the command, e.g. `fishfarm override feed tank=T3 grams=40`.
    Prints the controller's reply; exit 0 if accepted, 1 if refused, 2 on bad input or no answer.
    """
    if not _COMMAND.match(command):
        raise BadInput("COMMAND", command, "lower-case letters, digits, _ and - only")
    if command == "estop":
        fields = estop_fields(args)
    else:
        # (unknown options reach ARGS, for the e-stop's sake: elsewhere they are what click said)
        if (stray := next((w for w in args if w.startswith("-") and "=" not in w), None)) is not None:
            raise BadInput(stray, None, "no such option")
        fields = parse_args(args)
    payload = {"operator": operator, **({"reason": reason} if reason else {}), **fields}
    if command != "estop":
        # a reply lost on the way must not cost a second mortality or feed: the id to send it
        # again with is said if none comes (controller.override_requests)
        payload.setdefault("request", uuid.uuid4().hex)
    again = (f"; it may have been carried out: add request={payload['request']} to send it again "
             "without doing it twice") if "request" in payload else ""
    reply = _ask(connect, user, password, site, timeout_s, f"override/{command}", payload, ca, again)
    click.echo(json.dumps(reply, ensure_ascii=False))
    return 0 if reply.get("ok") is True else 1


# an e-stop is never held back for a detail: controller.cli.refuse_repeated leaves its options be
override.takes_anything = lambda args: args[:1] == ["estop"]


@click.command()
@click.option("--json", "as_json", is_flag=True, help="print the snapshot as JSON.")
@_connection_options
def status(as_json, connect, user, password, ca, site, timeout_s):
    """Show the controller's state: tanks (demand, fed/ration), feeder, cleaner, alarms."""
    snapshot = _ask(connect, user, password, site, timeout_s, "status", None, ca)
    if as_json:
        click.echo(json.dumps(snapshot, ensure_ascii=False, indent=2))
    else:
        click.echo(render_status(snapshot))
    return 0


# ---------------------------------------------------------------- the readable table

def _tanks(snapshot: dict) -> list[dict]:
    tanks = snapshot.get("tanks") or []
    if isinstance(tanks, dict):  # {"T1": {...}} as well as [{"tank": "T1", ...}]
        tanks = [{"tank": k, **(v if isinstance(v, dict) else {})} for k, v in tanks.items()]
    return [t for t in tanks if isinstance(t, dict)]


def _num(value, unit: str = "") -> str:
    """A number as an operator reads it: an integer whole (a state code 1, not 1.0), a small
    fraction to two significant digits (coverage 0.0012, not 0.0)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return "-"
    if isinstance(value, int):
        return f"{value}{unit}"
    if 0 < abs(value) < 0.05:
        return f"{value:.2g}{unit}"
    return f"{value:.0f}{unit}" if abs(value) >= 10 else f"{value:.1f}{unit}"


def _demand(tank: dict) -> str:
    """'yes 0.40/s', 'yes' or '-', from demand as a flag, a rate, or {"rate_hz": ...}."""
    demand, rate = tank.get("demand"), tank.get("rate_hz")
    if isinstance(demand, dict):
        demand, rate = True, demand.get("rate_hz", rate)
    elif isinstance(demand, int | float) and not isinstance(demand, bool):
        demand, rate = demand > 0, demand
    if not demand:
        return "-"
    return f"yes {rate:.2f}/s" if isinstance(rate, int | float) and not isinstance(rate, bool) else "yes"


def render_status(snapshot: dict) -> str:
    """The status snapshot as text: one row per tank, then feeder, cleaner and active alarms.
    Missing fields show as '-': the table never fails on a snapshot it does not fully know."""
    rows = [("tank", "demand", "fed/ration g", "pellet")]
    for t in _tanks(snapshot):
        ration = t.get("ration_g", t.get("grams"))
        rows.append((str(t.get("tank", t.get("id", "?"))), _demand(t),
                     f"{_num(t.get('fed_g'))}/{_num(ration)}", _num(t.get("pellet_mm"), " mm")))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = [f"site {snapshot.get('site', '?')}  {snapshot.get('t', '')}".rstrip()]
    lines += ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    for name in ("feeder", "cleaner"):
        part = snapshot.get(name)
        if isinstance(part, dict):
            extras = ", ".join(f"{k} {_num(v)}" for k, v in part.items()
                               if k not in ("t", "state") and isinstance(v, int | float))
            lines.append(f"{name}: {part.get('state', '-')}" + (f" ({extras})" if extras else ""))
    survey = snapshot.get("survey")
    if isinstance(survey, dict):
        lines.append(survey_line(survey))
    contacts = snapshot.get("contacts")
    if isinstance(contacts, dict) and (contacts.get("malformed") or contacts.get("lost")
                                       or contacts.get("unknown_sensors")):
        unknown = contacts.get("unknown_sensors")
        lines.append(f"contacts: {_num(contacts.get('malformed'))} lines rejected, {_num(contacts.get('lost'))} "
                     "missing" + (f"; unknown sensors {', '.join(map(str, unknown))}"
                                  if isinstance(unknown, list) and unknown else ""))
    alarms = [a for a in snapshot.get("alarms") or [] if isinstance(a, dict) and a.get("active", True)]
    for a in alarms:
        lines.append(f"ALARM {a.get('severity', '?')} {a.get('source', '')}: {a.get('text', '')}".rstrip())
    # whatever answered may not be ours: no escape sequence reaches the operator's terminal
    return "\n".join(printable(line, 1000) for line in lines)
