"""What the operator at the terminal sees: one status line per tank, refreshed live.

On a terminal a rich table is redrawn in place, and while it is shown every log line that
would reach the terminal is printed through the same rich Console instead, so it lands above
the table and the table stays whole (two writers on one screen garble each other: the table is
redrawn by moving the cursor up over its own height). The lines keep their formatter, so their
farm-time stamps. The heading is two short lines cut to the terminal's width, never wrapped.
Without a terminal (a service log) nothing changes: one compact line per tank is logged
every ``log_every_wall_s``, plain, on stderr like every other line.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import re
import sys

log = logging.getLogger("fishfarm.status")


def alarm_label(alarm: dict) -> str:
    """A standing alarm, or one cleared that nobody acknowledged yet (status lists both)."""
    return "ALARM" if alarm.get("active", True) else "CLEARED, unacknowledged:"


def cleaner_line(cleaner: dict) -> str:
    """The pond cleaner in one line: state, where, heading, share of the pond cleaned, the float."""
    where = "float not seen" if cleaner.get("x_m") is None else (
        f"at ({cleaner['x_m']:.2f}, {cleaner['y_m']:.2f}) m {math.degrees(cleaner['heading_rad'] or 0.0):.0f}°")
    coverage = cleaner.get("coverage")
    cleaned = "" if coverage is None else f", {100 * coverage:.1f} % cleaned"
    tracking = cleaner.get("tracking")
    return f"cleaner: {cleaner['state']} {where}{cleaned}" + (f", float {tracking}" if tracking else "")


def _where(feeder: dict) -> str:
    """Where the feeder is and what its hopper holds; '-' for what is not known yet (at start)."""
    def known(v, unit):
        return "-" if v is None else f"{v} {unit}"
    return f"at {known(feeder.get('position_m'), 'm')}, hopper {known(feeder.get('hopper_g'), 'g')}"


def survey_line(survey: dict) -> str:
    """The survey under way (pairs captured of those asked, fish measured, visits) and those asked for."""
    cur = survey.get("current")
    line = "survey: none under way"
    if isinstance(cur, dict):
        n = {k: cur.get(k) if isinstance(cur.get(k), int) and not isinstance(cur.get(k), bool) else "-"
             for k in ("captured", "pairs", "fish", "visits")}
        line = (f"survey: {cur.get('tank', '?')} ({cur.get('why', '-')}) {n['captured']}/{n['pairs']} pairs, "
                f"{n['fish']} fish, {n['visits']} visits")
        if isinstance(cur.get("held"), str):          # not under way now: what holds it
            line += f", held: {cur['held']}"
    asked = survey.get("asked")
    if isinstance(asked, list) and asked:
        line += "; asked: " + ", ".join(str(t) for t in asked)
    return line


def _survey_under_way(status: dict) -> list[str]:
    """The survey line, while one is under way or asked for (the feeder's 'surveying' says no more)."""
    survey = status.get("survey")
    if not isinstance(survey, dict) or (survey.get("current") is None and not survey.get("asked")):
        return []
    return [survey_line(survey)]


def tank_lines(status: dict) -> list[str]:
    feeder = status["feeder"]
    lines = [f"{status['t']}  feeder {feeder['state']:<10} {_where(feeder)}"]
    lines += [f"  {line}" for line in _survey_under_way(status)]
    if status.get("cleaner") is not None:
        lines.append(f"  {cleaner_line(status['cleaner'])}")
    for tank_id, tank in status["tanks"].items():
        demand = "DEMAND" if tank["demand"] else "quiet "
        pct = 100.0 * tank["fed_g"] / tank["ration_g"] if tank["ration_g"] else 0.0
        lines.append(f"  {tank_id:<6} {demand}  fed {tank['fed_g']:>8.1f} / {tank['ration_g']:>8.1f} g "
                     f"({pct:5.1f} %)  pellet {tank['pellet_mm']} mm")
    for alarm in status["alarms"]:
        lines.append(f"  {alarm_label(alarm)} {alarm['severity']} {alarm['source']}: {alarm['text']}")
    return lines


def heading(status: dict) -> list[str]:
    """The table's heading: where and when, then the feeder, then the pond cleaner if there is one.
    Each fits 80 columns for a usual site."""
    feeder = status["feeder"]
    lines = [f"fishfarm {status['site']}  {status['t']}", f"feeder: {feeder['state']} {_where(feeder)}",
             *_survey_under_way(status)]
    if status.get("cleaner") is not None:
        lines.append(cleaner_line(status["cleaner"]))
    return lines


_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def _one_row(text: str, style: str = ""):
    """A line that never wraps: cut with an ellipsis at the console's width (the full text is in the log).
    A newline or escape in an alarm's text would break the row or the screen: each becomes a space."""
    from rich.text import Text
    return Text(_CONTROL.sub(" ", text), style=style, no_wrap=True, overflow="ellipsis")


MAX_ALARM_ROWS = 5


def render(status: dict, height: int | None = None):
    """The whole live view: heading, one row per tank, one row per active alarm. Given the
    terminal's ``height``, only the tank rows that fit are built (a rich table costs about a
    millisecond a row to lay out), and a last row says how many more ``fishfarm status`` has."""
    from rich.console import Group
    from rich.table import Table
    table = Table()
    for col in ("tank", "demand", "fed today (g)", "ration (g)", "%", "pellet", "water"):
        table.add_column(col, justify="right" if col != "tank" else "left", no_wrap=True)
    alarms = [_one_row(f"{alarm_label(a)} {a['severity']} {a['source']}: {a['text']}", "bold red")
              for a in status["alarms"][:MAX_ALARM_ROWS]]
    if len(status["alarms"]) > MAX_ALARM_ROWS:
        alarms.append(_one_row(f"... {len(status['alarms']) - MAX_ALARM_ROWS} more alarms: fishfarm status",
                               "bold red"))
    top, *machines = heading(status)
    tanks = list(status["tanks"].items())
    shown = tanks
    if height is not None:
        room = height - 6 - len(machines) - len(alarms)   # heading, table 4 (borders, header), Live's cursor 1
        if len(tanks) > room:
            shown = tanks[:max(1, room - 1)]
    for tank_id, tank in shown:
        pct = 100.0 * tank["fed_g"] / tank["ration_g"] if tank["ration_g"] else 0.0
        table.add_row(tank_id, "[bold yellow]DEMAND[/]" if tank["demand"] else "-", f"{tank['fed_g']:.1f}",
                      f"{tank['ration_g']:.1f}", f"{pct:.0f}", f"{tank['pellet_mm']} mm", _water(tank))
    more = [_one_row(f"... {len(tanks) - len(shown)} more tanks: fishfarm status")] if len(shown) < len(tanks) else []
    return Group(_one_row(top, "bold"), *map(_one_row, machines), table, *more, *alarms)


def _water(tank: dict) -> str:
    """The water the ration is read at: measured, or the configured figure (marked)."""
    celsius = tank.get("water_temp_c")
    if celsius is None:
        return "-"
    return f"{celsius:.1f} °C" + ("" if tank.get("water_temp_source") == "sensor" else " (config)")


class Frame:
    """A view laid out once, in a worker thread, then only replayed: a log line printed above the
    live table redraws the table, and must not lay it out again on the event loop."""

    def __init__(self, renderable):
        self.renderable = renderable
        self._lines: list | None = None
        self._width: int | None = None

    def lay_out(self, console) -> Frame:
        self._lay_out(console, console.options)
        return self

    def _lay_out(self, console, options) -> None:
        if self._lines is None or self._width != options.max_width:      # the terminal was resized
            from rich.segment import Segment
            lines = console.render_lines(self.renderable, options.update(height=None), pad=False)
            self._lines = [list(Segment.simplify(line)) for line in lines]     # fewer pieces to replay
            self._width = options.max_width

    def __rich_console__(self, console, options):
        from rich.segment import Segment
        self._lay_out(console, options)
        for i, line in enumerate(self._lines):
            if i:
                yield Segment.line()
            yield from line


class ConsoleLogHandler(logging.Handler):
    """Log lines printed through the rich Console that draws the live table: above it, whole.

    ``soft_wrap``: a line longer than the terminal is wrapped by the terminal, not cut into
    lines by rich, so a copied line is the line that was logged."""

    def __init__(self, console, level=logging.NOTSET):
        super().__init__(level)
        self.console = console

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from rich.text import Text
            self.console.print(Text(self.format(record)), soft_wrap=True, highlight=False)
        except Exception:
            self.handleError(record)


def _writes_to_terminal(handler: logging.Handler) -> bool:
    stream = getattr(handler, "stream", None)
    if type(handler) is not logging.StreamHandler or stream is None:
        return False
    try:
        return stream.isatty()
    except (AttributeError, ValueError):        # closed or not a file
        return False


@contextlib.contextmanager
def logging_through(console, logger: logging.Logger | None = None):
    """While inside, the logger's handlers that write to a terminal print through ``console``
    instead, with their own formatter, level and filters; on leaving, they are put back.
    A handler writing to a file or a pipe (``2>run.log``) is left alone: it cannot garble the table."""
    logger = logger or logging.getLogger()
    swapped: list[tuple[logging.Handler, logging.Handler]] = []
    for handler in list(logger.handlers):
        if _writes_to_terminal(handler):
            rich_handler = ConsoleLogHandler(console, handler.level)
            rich_handler.setFormatter(handler.formatter)
            for f in handler.filters:
                rich_handler.addFilter(f)
            swapped.append((handler, rich_handler))
    for old, new in swapped:
        logger.addHandler(new)
        logger.removeHandler(old)
    try:
        yield [new for _, new in swapped]
    finally:
        for old, new in swapped:
            logger.addHandler(old)
            logger.removeHandler(new)


class LiveStatus:
    """The live table on ``console``, with the terminal's log lines routed above it while shown."""

    def __init__(self, console, get_status):
        self.console, self.get_status = console, get_status
        self._stack = contextlib.ExitStack()
        self.live = None

    def frame(self) -> Frame:
        """The current status as a frame to lay out; ``get_status`` is called here, on the caller's thread."""
        return Frame(render(self.get_status(), self.console.height))

    def __enter__(self):
        from rich.live import Live
        # redrawn by update() only, not by a thread of its own: frames change once a second
        self.live = Live(self.frame().lay_out(self.console), console=self.console, auto_refresh=False,
                         transient=False)
        with self._stack as stack:      # on leaving: the table's last frame first, then plain lines again
            stack.enter_context(logging_through(self.console))
            stack.enter_context(self.live)
            self._stack = stack.pop_all()
        return self

    def update(self, frame: Frame | None = None) -> None:
        """Show ``frame`` (laid out already, or here), or the current status."""
        self.live.update((frame or self.frame()).lay_out(self.console), refresh=True)

    def __exit__(self, *exc):
        return self._stack.__exit__(*exc)


async def show(get_status, every_wall_s: float = 1.0, log_every_wall_s: float = 60.0, console=None) -> None:
    """Forever (cancel to stop): the live table on a terminal, else the status as log lines."""
    if console is None and sys.stdout.isatty():
        from rich.console import Console
        console = Console()
    if console is not None:
        with LiveStatus(console, get_status) as live:
            while True:
                await asyncio.sleep(every_wall_s)
                live.update(await asyncio.to_thread(live.frame().lay_out, console))
    else:
        while True:
            await asyncio.sleep(log_every_wall_s)
            for line in tank_lines(get_status()):
                log.info("%s", line)
