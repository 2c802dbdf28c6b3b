"""Every number a command takes is finite: nan passes a plain range check (it compares false) and
an infinite speed, duration or timeout breaks what uses it (a farm clock past year 9999, a timer)."""
from __future__ import annotations

import click
import pytest

from controller.cli import main
from controller.cli.params import MAX_RUN_SPEED, MAX_SPEED, SPEED, Finite

FLOAT_OPTIONS = [
    ["run", "--duration"], ["run", "--speed"], ["run", "--epoch-wall"], ["run", "--epoch-farm"],
    ["sim", "--speed"], ["sim", "--epoch-wall"], ["sim", "--epoch-farm"],
    ["worker", "--duration"],
    ["override", "status", "--timeout"],
    ["track", "--frames", "x", "--tower", "y", "--json", "z", "--lost-after"],
    ["calibrate", "chessboard", "--left", "a", "--right", "b", "--out", "o.json", "--square-mm"],
    ["report", "--tank", "T1", "--target"],
]


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "NaN"])
@pytest.mark.parametrize("words", FLOAT_OPTIONS, ids=lambda w: " ".join(w[:1] + w[-1:]))
def test_nan_and_inf_exit_2_naming_the_option(capsys, words, value):
    assert main([*words, value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words[-1] in err[0] and value.lower() in err[0].lower(), err


def test_speeds_past_what_a_simulated_farm_keeps_up_with_are_refused_and_up_to_it_taken():
    assert MAX_RUN_SPEED < MAX_SPEED
    assert SPEED.convert(str(MAX_RUN_SPEED), None, None) == MAX_RUN_SPEED
    for past in (MAX_RUN_SPEED * 1.01, 1e5, MAX_SPEED):
        with pytest.raises(click.BadParameter):
            SPEED.convert(str(past), None, None)
    with pytest.raises(click.BadParameter):
        SPEED.convert("0", None, None)


@pytest.mark.parametrize("text, want", [("0", 0.0), ("-1e300", -1e300), ("1e300", 1e300), ("2.5", 2.5)])
def test_finite_numbers_pass_whole(text, want):
    assert Finite().convert(text, None, None) == want
