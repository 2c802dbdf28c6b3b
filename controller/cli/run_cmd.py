"""``fishfarm run``: the controller process."""
from __future__ import annotations

import asyncio
import logging

import click

from controller.cli.params import FARM_INSTANT, SPEED, Finite, check_clock_options
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
@click.option("--epoch-wall", type=FARM_INSTANT, default=None,
              help="wall time (Unix s) at which farm time is --epoch-farm: a restart continues farm time")
@click.option("--epoch-farm", type=FARM_INSTANT, default=None,
              help="farm time (Unix s) at --epoch-wall (alone: farm time starts there now)")
@click.option("--clock", "clock_path", type=click.Path(dir_okay=False, exists=True), default=None,
              help="an elastic clock file shared with the simulator (devices/elastic_clock.py), in place of "
                   "--speed/--epoch-*")
@click.option("--log-level", default="info", show_default=True,
              type=click.Choice(["debug", "info", "warning", "error"], case_sensitive=False))
@click.option("--no-console", is_flag=True, help="no live status table, even on a terminal")
def run(config_path, duration, speed, epoch_wall, epoch_farm, clock_path, log_level, no_console):
    """The controller: demand filter, feeding robot, ledger, bus."""
    from controller.app import Controller, install_signal_handlers
    from controller.config import load_config
    from devices.clock import ScaledClock

    check_clock_options(speed, epoch_wall, epoch_farm, clock_path)
    cfg = load_config(config_path)
    all_sim = all(s["driver"] == "sim" for s in cfg.devices.values())
    if speed != 1.0 and not all_sim and epoch_wall is None:
        raise BadInput(config_path, "devices", "--speed needs every device simulated (driver = \"sim\")")
    follows = all_sim and clock_path is None and epoch_wall is None and epoch_farm is None
    if clock_path is not None:
        from controller.cli.sim_cmd import elastic
        clock = elastic(clock_path, "controller")
    elif epoch_wall is not None:
        clock = ScaledClock(speed, epoch_wall, epoch_farm if epoch_farm is not None else epoch_wall)
    elif epoch_farm is not None:          # farm time starts there now (as `fishfarm sim` takes it)
        clock = ScaledClock.starting(speed, epoch_farm)
    else:
        clock = ScaledClock.starting(speed) if speed != 1.0 or all_sim else ScaledClock.real()
    clock, carried = _after_the_ledger(cfg, clock, follows, clock_path is not None)
    setup_logging(clock, log_level)
    if carried is not None:
        logging.getLogger("fishfarm").info("farm time carries on from the ledger's last entry (%s), not the "
                                           "wall clock: a simulated farm's time never runs back", clock.iso(carried))

    _warm(cfg)

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


def _warm(cfg) -> None:
    """What the controller's start would do on its event loop for seconds (~1.5 s quiet, ~5 s at a
    load of 8): import the float tracker's filterpy and scipy, work out the demand filter's beat
    thresholds. Done first, before the signal handlers: a SIGINT or SIGTERM in a start's first
    seconds had waited for the loop, and twice in twelve the stop's watchdog ended it (exit 70)."""
    import scipy.special  # noqa: F401  (the growth fits')

    from controller.config import validate_section
    from controller.demand import DemandFilter, DemandParams
    params = validate_section(DemandParams, cfg.demand, cfg.path, "demand")
    DemandFilter(params, {t.id: list(t.sensors) for t in cfg.tanks})          # its thresholds, cached
    if cfg.cleaning is not None:
        import vision.float_track  # noqa: F401


AHEAD_S = 300.0         # a ledger this far (farm s) ahead of the clock: the clock went back


def _after_the_ledger(cfg, clock, follows: bool, clock_file: bool = False):
    """(clock, the ledger time it carries on from or None). A simulated farm's clock with no epoch
    given starts at the wall clock: restarted on a ledger a faster run had taken days ahead, farm
    time ran back, and demands of the 'future' were served at once, one of them twice. Such a clock
    now carries on from the ledger's last entry; any other clock (a farm's wall clock, epochs or a
    clock file given) that the ledger is ahead of is refused."""
    from controller.store import ledger_time
    from devices.clock import ScaledClock
    latest = ledger_time(cfg.store.path)
    now = clock.now()
    if latest is None or latest <= now + (0.0 if follows else AHEAD_S):
        return clock, None
    if follows:
        from devices.clock_file import farm_range_fault
        if farm_range_fault(latest + 86_400.0) is not None:
            # carried on from there, the simulator's --epoch-farm (never given) was refused, naming it
            raise BadInput("store.path", cfg.store.path,
                           f"the ledger's last entry ({clock.iso(latest)}) is at the end of the farm's years "
                           "2000-2199: a simulated farm cannot carry on from it (start a new ledger)")
        return ScaledClock.starting(clock.speed, latest), latest
    carry = ("a clock file whose farm time starts after it (fishfarm clock --farm-start)" if clock_file
             else "--epoch-wall/--epoch-farm that carry on from the ledger")
    raise BadInput("store.path", cfg.store.path,
                   f"the ledger's last entry ({clock.iso(latest)}) is {(latest - now) / 3600:.1f} h after this "
                   f"clock's farm time ({clock.iso(now)}): the clock went back (give {carry}, or start a new "
                   "ledger)")


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
