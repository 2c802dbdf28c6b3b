"""``fishfarm calibrate dlt|chessboard|import``: each method in its own module."""
from __future__ import annotations

import click

from controller.cli import LazyGroup


class _Methods(LazyGroup):
    table = {
        "dlt": "controller.cli.calibrate_dlt:dlt",
        "chessboard": "controller.cli.calibrate_chessboard:chessboard",
        "import": "controller.cli.calibrate_import:import_",
    }


@click.group(cls=_Methods)
def calibrate():
    """Calibrate the stereo rig: from a measured grid (DLT) or a printed chessboard, or import one."""
