"""``fishfarm run``: the controller process."""
from __future__ import annotations

import asyncio
import logging

import click

from controller.cli.params import SPEED, Finite
from controller.errors import BadInput


class FarmTimeFormatter(logging.Formatter):
    """Log lines stamped with farm time, which is what an operator compares with the ledger."""

    def __init__(self, clock):
        super().__init__("%(farmtime)s %(levelname)-7s %(name)s: %(message)s")
        self.clock = clock

    def format(self, record):
        record.farmtime = self.clock.iso(self.clock.at(record.created))
        return super().format(record)


def setup_logging(clock, level: str) -> None:
    handler = logging.StreamHandler()
    handler.setFormatter(FarmTimeFormatter(clock))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    for noisy in ("pymodbus", "can", "zenoh", "transitions"):
        logging.getLogger(noisy).setLevel(logging.WARNING if level.upper() != "DEBUG" else logging.INFO)
    # pymodbus logs every failed reconnect at ERROR (with a hex dump of the last frames): the
    # driver alarms the loss once and the recovery once; the retries between are debug lines
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL if level.upper() != "DEBUG" else logging.DEBUG)


@click.command()
@click.option("--config", "config_path", default="config/farm.toml", show_default=True,
              type=click.Path(dir_okay=False), help="farm.toml")
@click.option("--duration", type=Finite(min=0, min_open=True), default=None,
              help="stop after S farm seconds (default: run until stopped)")
@click.option("--speed", type=SPEED, default=1.0, show_default=True,
              help="simulated time runs X times faster than real time (simulated devices only)")
@click.option("--epoch-wall", type=Finite(), default=None,
              help="wall time (Unix s) at which farm time is --epoch-farm: a restart continues farm time")
@click.option("--epoch-farm", type=Finite(), default=None, help="farm time (Unix s) at --epoch-wall")
@click.option("--clock", "clock_path", type=click.Path(dir_okay=False, exists=True), default=None,
              help="an elastic clock file shared with the simulator (devices/elastic_clock.py)")
@click.option("--log-level", default="info", show_default=True,
              type=click.Choice(["debug", "info", "warning", "error"], case_sensitive=False))
@click.option("--no-console", is_flag=True, help="no live status table, even on a terminal")
def run(config_path, duration, speed, epoch_wall, epoch_farm, clock_path, log_level, no_console):
    """The controller: demand filter, feeding robot, ledger, bus."""
    from controller.app import Controller, install_signal_handlers
    from controller.config import load_config
    from devices.clock import ScaledClock

    cfg = load_config(config_path)
    all_sim = all(s["driver"] == "sim" for s in cfg.devices.values())
    if speed != 1.0 and not all_sim and epoch_wall is None:
        raise BadInput(config_path, "devices", "--speed needs every device simulated (driver = \"sim\")")
    if clock_path is not None:
        from controller.cli.sim_cmd import elastic
        clock = elastic(clock_path, "controller")
    elif epoch_wall is not None:
        clock = ScaledClock(speed, epoch_wall, epoch_farm if epoch_farm is not None else epoch_wall)
    else:
        clock = ScaledClock.starting(speed) if speed != 1.0 else ScaledClock.real()
    setup_logging(clock, log_level)

    async def main():
        controller = Controller(cfg, clock, duration_s=duration)
        install_signal_handlers(controller)
        console = None
        if not no_console:
            from controller.console import show
            console = asyncio.create_task(_show_when_up(controller, show))
        try:
            await controller.run()
        finally:
            if console is not None:
                console.cancel()

    _run_to_the_end(main())
    return 0


def _run_to_the_end(main, leftovers_s: float = 0.5) -> None:
    """asyncio.run, except that tasks still running at the end (one that ignored its cancel) are
    cancelled and given ``leftovers_s``, not waited for without end: a stop must end the process."""
    loop = asyncio.new_event_loop()
    try:
        asyncio.set_event_loop(loop)
        loop.run_until_complete(main)
    finally:
        try:
            left = [t for t in asyncio.all_tasks(loop) if not t.done()]
            for task in left:
                task.cancel()
            if left:
                loop.run_until_complete(asyncio.wait(left, timeout=leftovers_s))
        finally:
            asyncio.set_event_loop(None)
            loop.close()


async def _show_when_up(controller, show):
    while not hasattr(controller, "overrides"):
        await asyncio.sleep(0.1)
    await show(controller.status)
