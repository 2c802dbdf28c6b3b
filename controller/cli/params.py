"""Option types the commands share."""
from __future__ import annotations

import math

import click

# farm seconds per wall second at most: a farm year in ~30 s, and farm times stay dates (past
# ~1e7 a day's run overflows what the clock can print)
MAX_SPEED = 1e6


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
