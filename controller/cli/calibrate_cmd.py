"""``fishfarm calibrate dlt|chessboard|import|tower``: each method in its own module."""
from __future__ import annotations

import click

from controller.cli import LazyGroup


class _Methods(LazyGroup):
    table = {
        "dlt": "controller.cli.calibrate_dlt:dlt",
        "chessboard": "controller.cli.calibrate_chessboard:chessboard",
        "import": "controller.cli.calibrate_import:import_",
        "tower": "controller.cli.calibrate_tower:tower",
    }


@click.group(cls=_Methods)
def calibrate():
    """Calibrate the stereo rig (measured grid, chessboard, or import), or the tower camera's pond map."""
