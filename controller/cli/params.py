"""Option types the commands share."""
from __future__ import annotations

import math
import re

import click

# MAX_SPEED: farm seconds per wall second at most: a farm year in ~30 s, and farm times stay dates
# (past ~1e7 a day's run overflows what the clock can print); farm instants in the years 2000-2199
from devices.clock_file import MAX_SPEED, farm_range_fault

__all__ = ["FARM_INSTANT", "MAX_RUN_SPEED", "MAX_SPEED", "SPEED", "Finite", "check_clock_options",
           "image_size_option"]


class Finite(click.FloatRange):
    """A number in a range, never nan or inf: click's range check lets nan through (every
    comparison with it is false), and an infinite duration, speed or timeout breaks what uses it."""

    name = "finite number"

    def convert(self, value, param, ctx):
        rv = super().convert(value, param, ctx)
        if not math.isfinite(rv):
            self.fail(f"{value} is not a finite number", param, ctx)
        return rv

    def _describe_range(self) -> str:
        # no bounds: no "[x<=None]" in the help
        return "" if self.min is None and self.max is None else super()._describe_range()


# what a whole simulated farm keeps up with, `run` and `sim --speed` (the elastic clock's fast spans
# go further: nothing talks then): at 1e5 and 1e6 the simulator spent itself generating the fish's
# contacts of farm days each wall second, every device timed out, nothing was fed, and an e-stop was
# never confirmed; at 1e4 the demo farm feeds
MAX_RUN_SPEED = 1e4
SPEED = Finite(min=0, min_open=True, max=MAX_RUN_SPEED)


class FarmInstant(Finite):
    """Unix seconds of a farm (or wall) instant in the years 2000-2199: --epoch-farm 1e300 froze farm
    time, -1e10 ran the farm in 1653, and an instant past 9999 broke every log line."""

    name = "farm instant (Unix seconds)"

    def convert(self, value, param, ctx):
        rv = super().convert(value, param, ctx)
        if (fault := farm_range_fault(rv)) is not None:
            self.fail(fault, param, ctx)
        return rv


FARM_INSTANT = FarmInstant()


def _given(name: str, otherwise: bool) -> bool:
    """Whether the command line gave option ``name`` (``--speed 1`` is given though it is the
    default: compared with the default, it passed beside --clock); ``otherwise`` outside a command."""
    ctx = click.get_current_context(silent=True)
    if ctx is None or name not in ctx.params:
        return otherwise
    from click.core import ParameterSource
    return ctx.get_parameter_source(name) not in (ParameterSource.DEFAULT, None)


def check_clock_options(speed, epoch_wall, epoch_farm, clock_path, hear=None) -> None:
    """Options of ``run`` and ``sim`` that cannot all be meant: each was ignored without a word."""
    from controller.errors import BadInput
    if clock_path is not None:
        given = [o for o, v in (("--speed", _given("speed", speed != 1.0)), ("--epoch-wall", epoch_wall is not None),
                                ("--epoch-farm", epoch_farm is not None)) if v]
        if given:
            raise BadInput("--clock", None, f"the clock file sets farm time: not with {' or '.join(given)}")
    elif hear is not None:
        raise BadInput("--hear", None, "only with --clock: the simulator hears demands to let an elastic "
                                       "clock speed on")


def image_size_option(ctx, param, value):
    """``--image-size WxH`` (a click callback): (width, height) in pixels, or None. Each side
    1..MAX_IMAGE_PX, the range every reader of a calibration's size holds it to: a size past it
    reached numpy as an integer too big for it, or was written to a file its reader refused."""
    from vision.calib_file import MAX_IMAGE_PX
    if value is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value)
    if not m or not all(1 <= int(s) <= MAX_IMAGE_PX for s in (m[1], m[2])):
        raise click.BadParameter(f"{value!r}: expected WIDTHxHEIGHT in pixels (e.g. 1280x960), "
                                 f"each side 1..{MAX_IMAGE_PX}")
    return int(m[1]), int(m[2])
