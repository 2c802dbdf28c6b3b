"""Option types the commands share."""
from __future__ import annotations

import math

import click

# MAX_SPEED: farm seconds per wall second at most: a farm year in ~30 s, and farm times stay dates
# (past ~1e7 a day's run overflows what the clock can print); farm instants in the years 2000-2199
from devices.clock_file import MAX_SPEED, farm_range_fault

__all__ = ["FARM_INSTANT", "MAX_RUN_SPEED", "MAX_SPEED", "SPEED", "Finite"]


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

    name = "farm instant"

    def convert(self, value, param, ctx):
        rv = super().convert(value, param, ctx)
        if (fault := farm_range_fault(rv)) is not None:
            self.fail(fault, param, ctx)
        return rv


FARM_INSTANT = FarmInstant()
