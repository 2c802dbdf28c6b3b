"""The live status table on a terminal: log lines land above it, whole and farm-stamped; the table and its
heading stay whole at 80 and 160 columns; without a terminal, logging is untouched."""
import datetime as dt
import io
import logging
import re
import time

import pytest
from rich.console import Console

from controller.cli.run_cmd import setup_logging
from controller.console import MAX_ALARM_ROWS, Frame, LiveStatus, logging_through, render
from devices.clock import ScaledClock

FARM_EPOCH = dt.datetime(2031, 3, 7, 6, 0, tzinfo=dt.UTC).timestamp()   # far from the wall: a stamp shows which
ASK = "auger on for T6: 60.0 g, 16.3 s after the ask;" + " the carriage stood over T6 the whole run" * 3


def farm_status(site="demo", alarms=(), tanks=8):
    return {"t": "2031-03-07T06:00:00.000Z", "site": site,
            "feeder": {"state": "dispensing", "position_m": 10.5, "hopper_g": 5281.1},
            "tanks": {f"T{i}": {"demand": i == 3, "fed_g": 60.0 * i, "ration_g": 1123.2, "pellet_mm": 2.0}
                      for i in range(1, tanks + 1)},
            "alarms": list(alarms)}


class Terminal(io.StringIO):
    """One terminal that stdout and stderr both write to, as under ``fishfarm run`` at a shell, and what
    it shows: printable text auto-wrapping at ``width``, CR, LF, cursor up (ESC[nA), erase line (ESC[2K);
    colours and cursor visibility change nothing on the screen's text."""

    def __init__(self, width):
        super().__init__()
        self.width = width

    def isatty(self):
        return True

    def screen(self) -> list[str]:
        rows: list[list[str]] = [[]]
        row = col = 0
        for m in re.finditer(r"\x1b\[([0-9;?]*)([A-Za-z])|(.)", self.getvalue(), re.S):
            code, command, char = m.groups()
            if command == "A":
                row = max(0, row - int(code or 1))
            elif command == "K" and code == "2":
                rows[row] = []
            elif command is not None:
                continue
            elif char == "\n":
                row, col = row + 1, 0
            elif char == "\r":
                col = 0
            else:
                if col == self.width:                     # wraps when the next character comes
                    row, col = row + 1, 0
                rows.extend([] for _ in range(row + 1 - len(rows)))
                line = rows[row]
                line.extend(" " * (col + 1 - len(line)))
                line[col] = char
                col += 1
            rows.extend([] for _ in range(row + 1 - len(rows)))
        return ["".join(r) for r in rows]


@pytest.fixture
def root_logger():
    root = logging.getLogger()
    saved = root.handlers[:], root.level
    yield root
    root.handlers[:], level = saved
    root.setLevel(level)


def view_lines(status, width, height=None):
    console = Console(width=width, record=True, file=io.StringIO())
    console.print(render(status, height))
    return console.export_text().rstrip("\n").split("\n")


@pytest.mark.parametrize("width", [80, 160])
def test_the_heading_is_whole_at_80_and_160_columns(width):
    lines = view_lines(farm_status(alarms=[{"severity": "warning", "source": "rail", "text": "x" * 300}]), width)
    assert lines[:2] == ["fishfarm demo  2031-03-07T06:00:00.000Z", "feeder: dispensing at 10.5 m, hopper 5281.1 g"]
    assert lines[2].startswith("┏") and lines[-2].startswith("└")       # the table follows at once
    assert lines[-1].startswith("ALARM warning rail: xxx") and lines[-1].endswith("…") and len(lines[-1]) == width
    assert all(len(line) <= width for line in lines)


def test_an_alarm_text_with_a_newline_or_an_escape_stays_one_row():
    alarm = {"severity": "critical", "source": "override", "text": "stop\n2031-03-07 INFO forged\x1b[2J"}
    lines = view_lines(farm_status(alarms=[alarm]), 80)
    assert lines[-1] == "ALARM critical override: stop 2031-03-07 INFO forged [2J"


def test_a_long_site_name_is_cut_not_wrapped():
    lines = view_lines(farm_status(site="s" * 64), 80)
    assert lines[0].startswith("fishfarm ssss") and lines[0].endswith("…") and len(lines[0]) == 80
    assert lines[1].startswith("feeder: ")


@pytest.mark.parametrize("height", [30, 45])
def test_a_farm_taller_than_the_terminal_shows_the_rows_that_fit_and_says_how_many_more(height):
    alarms = [{"severity": "warning", "source": f"tank/T{i}", "text": "sensor stuck"} for i in range(7)]
    lines = view_lines(farm_status(tanks=100, alarms=alarms), 80, height)
    rows = [line for line in lines if line.startswith("│ T")]
    assert len(lines) == height - 1                                   # Live keeps a line for its cursor
    assert [r.split()[1] for r in rows] == [f"T{i}" for i in range(1, len(rows) + 1)]
    assert lines[-MAX_ALARM_ROWS - 2:] == [f"... {100 - len(rows)} more tanks: fishfarm status"] + [
        f"ALARM warning tank/T{i}: sensor stuck" for i in range(MAX_ALARM_ROWS)] + [
        "... 2 more alarms: fishfarm status"]
    assert view_lines(farm_status(tanks=20), 80, 45) == view_lines(farm_status(tanks=20), 80)   # room for all
    assert len([line for line in view_lines(farm_status(tanks=100), 80, 5) if line.startswith("│ T")]) == 1


def test_a_frame_is_laid_out_again_only_for_a_new_width():
    frame = Frame(render(farm_status()))
    wide = Console(width=160, file=io.StringIO())
    assert frame.lay_out(wide) is frame
    lines = frame._lines
    frame.lay_out(wide)
    assert frame._lines is lines
    narrow = Console(width=40, record=True, file=io.StringIO())
    narrow.print(frame)
    assert max(len(line) for line in narrow.export_text().splitlines()) <= 40


@pytest.mark.parametrize("width", [80, 160])
def test_a_log_line_during_the_live_table_lands_above_it_whole_and_farm_stamped(width, root_logger, monkeypatch):
    term = Terminal(width)
    monkeypatch.setattr("sys.stderr", term)                       # setup_logging's handler writes here
    setup_logging(ScaledClock(60.0, time.time(), FARM_EPOCH), "info")
    plain = root_logger.handlers[0]
    console = Console(file=term, width=width, force_terminal=True, record=True)
    status = farm_status()
    with LiveStatus(console, lambda: status) as live:
        logging.getLogger("fishfarm.feeder").info("%s", ASK)
        status["tanks"]["T6"]["fed_g"] = 420.0
        live.update()
        logging.getLogger("fishfarm.feeder").warning("hopper below %d g", 1500)
    assert root_logger.handlers == [plain]                          # plain lines on stderr again

    stamp = r"2031-03-07T06:0\d:\d\d\.\d{3}Z"
    exported = console.export_text()                                # each line as rich printed it: unbroken
    assert re.search(stamp + " INFO    fishfarm.feeder: " + re.escape(ASK) + "\n", exported)
    assert re.search(stamp + r" WARNING fishfarm.feeder: hopper below 1500 g\n", exported)

    screen = term.screen()
    while screen and not screen[-1].strip():
        screen.pop()
    view = view_lines(status, width)
    assert [row.rstrip() for row in screen[-len(view):]] == view    # the table, whole, at the bottom
    above = screen[:-len(view)]
    logged = "".join(above)                                         # the terminal wrapped the long line
    assert re.fullmatch(stamp + " INFO    fishfarm.feeder: " + re.escape(ASK)
                        + stamp + r" WARNING fishfarm.feeder: hopper below 1500 g", logged), above
    assert not any("fishfarm demo" in row or "┃" in row for row in above)   # no torn frame left behind


def test_without_a_terminal_logging_stays_plain(root_logger):
    to_file = logging.StreamHandler(io.StringIO())                  # fishfarm run 2>run.log
    root_logger.handlers[:] = [to_file]
    console = Console(file=io.StringIO(), width=80, force_terminal=True)
    with logging_through(console) as taken:
        assert taken == [] and root_logger.handlers == [to_file]
        logging.getLogger("fishfarm").warning("plain")
    assert to_file.stream.getvalue() == "plain\n"


@pytest.mark.parametrize("level, shown", [("info", False), ("debug", True)])
def test_a_modbus_reconnect_retry_is_a_debug_line_not_an_error(level, shown, root_logger, monkeypatch):
    """pymodbus logs each failed connect at ERROR: the dispenser's absence is alarmed once by the
    controller, so its retries show only at debug level."""
    from pymodbus.logging import Log

    err = io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    saved = logging.getLogger("pymodbus").level
    try:
        setup_logging(ScaledClock(60.0, time.time(), FARM_EPOCH), level)
        Log.error("Connection to (127.0.0.1, 1) failed: [Errno 111] Connection refused")
        Log.warning("Failed to connect [Errno 111] Connect call failed")
    finally:
        logging.getLogger("pymodbus").setLevel(saved)
    assert ("Connection refused" in err.getvalue()) is shown, err.getvalue()
    assert ("Failed to connect" in err.getvalue()) is shown, err.getvalue()


CLEANER = {"t": "2031-03-07T06:00:00.000Z", "state": "cleaning", "x_m": 12.345, "y_m": 4.5, "heading_rad": -1.5708,
           "coverage": 0.4567, "tracking": "predicted"}


@pytest.mark.parametrize("width", [80, 160])
def test_the_cleaner_has_its_row_under_the_feeder(width):
    lines = view_lines({**farm_status(), "cleaner": CLEANER}, width)
    assert lines[2] == "cleaner: cleaning at (12.35, 4.50) m -90°, 45.7 % cleaned, float predicted"
    assert lines[3].startswith("┏")
    lost = view_lines({**farm_status(), "cleaner": {**CLEANER, "x_m": None, "y_m": None, "heading_rad": None,
                                                    "state": "lost", "tracking": "lost"}}, width)
    assert lost[2] == "cleaner: lost float not seen, 45.7 % cleaned, float lost"
    tall = view_lines({**farm_status(tanks=100), "cleaner": CLEANER}, 80, 30)
    assert len(tall) == 29                                          # the row is counted in the room


def test_without_a_terminal_the_cleaner_is_a_log_line_too():
    from controller.console import tank_lines
    assert tank_lines({**farm_status(), "cleaner": CLEANER})[1].startswith("  cleaner: cleaning at (12.35, 4.50) m")
    assert not any("cleaner" in line for line in tank_lines(farm_status()))


def test_the_water_column_says_whether_the_temperature_was_measured():
    status = farm_status()
    tanks = list(status["tanks"])
    status["tanks"][tanks[0]].update(water_temp_c=19.25, water_temp_source="sensor")
    status["tanks"][tanks[1]].update(water_temp_c=22.0, water_temp_source="config")
    lines = view_lines(status, 120)
    row = {line.split("│")[1].strip(): line for line in lines if line.startswith("│")}
    assert "19.2 °C" in row[tanks[0]] and "config" not in row[tanks[0]]
    assert "22.0 °C (config)" in row[tanks[1]]
    assert row[tanks[2]].rstrip("│ ").endswith("-")            # a status without the figure


SURVEY = {"current": {"tank": "T4", "why": "schedule", "captured": 12, "pairs": 40, "fish": 25, "visits": 3},
          "asked": ["T2"]}


@pytest.mark.parametrize("width", [80, 160])
def test_a_survey_under_way_has_its_row_under_the_feeder_and_nothing_unknown_reads_none(width):
    """The table said only 'feeder: surveying at 8.0 m' (which tank, how far: only fishfarm status
    knew), and 'feeder: starting at None m, hopper None g' at start."""
    surveying = {**farm_status(), "feeder": {"state": "surveying", "position_m": 8.0, "hopper_g": 5281.1},
                 "survey": SURVEY}
    lines = view_lines(surveying, width)
    assert lines[1:3] == ["feeder: surveying at 8.0 m, hopper 5281.1 g",
                          "survey: T4 (schedule) 12/40 pairs, 25 fish, 3 visits; asked: T2"]
    idle = {**farm_status(), "survey": {"current": None, "asked": []}}
    assert not any("survey" in line for line in view_lines(idle, width))
    starting = {**farm_status(), "feeder": {"state": "starting", "position_m": None, "hopper_g": None}}
    assert view_lines(starting, width)[1] == "feeder: starting at -, hopper -"
    from controller.console import tank_lines
    assert tank_lines(surveying)[1] == "  survey: T4 (schedule) 12/40 pairs, 25 fish, 3 visits; asked: T2"
    assert "None" not in tank_lines(starting)[0]


def test_a_survey_held_by_its_tank_says_so_not_under_way():
    """Paused mid-survey, its session stays current: status read as a survey under way."""
    from controller.console import survey_line
    held = {"current": {**SURVEY["current"], "held": "paused"}, "asked": []}
    assert survey_line(held) == "survey: T4 (schedule) 12/40 pairs, 25 fish, 3 visits, held: paused"
    assert survey_line({**SURVEY, "current": {**SURVEY["current"], "held": None}}).endswith("3 visits; asked: T2")
