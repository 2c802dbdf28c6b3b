"""``fishfarm sim``: serve a config's simulated devices over their real protocols.

Started by ``fishfarm run`` for devices marked ``driver = "sim"``, or by hand / by the
hardware-in-loop tests, in which case the controller is pointed at the endpoints this
writes and joins the same timeline with ``--epoch-wall/--epoch-farm/--speed``.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import signal
import sys
import threading
from pathlib import Path

import click

from controller.cli.params import FARM_INSTANT, SPEED, check_clock_options


@click.command()
@click.option("--config", "config_path", default="config/farm.toml", show_default=True,
              type=click.Path(dir_okay=False))
@click.option("--endpoints", type=click.Path(dir_okay=False), required=True,
              help="write the real-driver config section of every simulated device here (JSON)")
@click.option("--truth", type=click.Path(dir_okay=False), default=None,
              help="append the ground truth of the run here (JSON lines)")
@click.option("--speed", type=SPEED, default=1.0, show_default=True)
@click.option("--epoch-wall", type=FARM_INSTANT, default=None, help="wall time at which farm time is --epoch-farm")
@click.option("--epoch-farm", type=FARM_INSTANT, default=None)
@click.option("--clock", "clock_path", type=click.Path(dir_okay=False, exists=True), default=None,
              help="an elastic clock file (devices/elastic_clock.py) shared with the controller: "
                   "replaces --speed/--epoch-*")
@click.option("--hear", "hear", default=None, metavar="tcp/HOST:PORT",
              help="with --clock: the controller's Zenoh endpoint; fish asking hold the clock slow only "
                   "until a demand for their tank is heard there (devices/sim/pace.py)")
@click.option("--log-level", default="warning", show_default=True,
              type=click.Choice(["debug", "info", "warning", "error"], case_sensitive=False))
def sim(config_path, endpoints, truth, speed, epoch_wall, epoch_farm, clock_path, hear, log_level):
    """Simulated farm: fish, contact hub, rail drive, dispenser, pond cleaner's thrusters and tower
    camera. SIGUSR1 power-cycles the dispenser."""
    from controller.config import load_config
    from devices.clock import ScaledClock
    from devices.sim.truth import TruthLog
    from devices.sim.world import SimFarm

    check_clock_options(speed, epoch_wall, epoch_farm, clock_path, hear)
    from controller.cli.output_paths import check_outputs
    check_outputs({"--endpoints": endpoints, "--truth": truth}, [config_path])
    import cv2
    # one thread, as the renderers' budgets are set (bench_pond_view): beside the controller and
    # the vision workers on the farm's cores, OpenCV's pool only spun, 0.142 against 0.121 CPU s a
    # survey still at 960x720 (the grow-out's largest cost)
    cv2.setNumThreads(1)
    logging.basicConfig(level=log_level.upper(), format="sim %(levelname)s %(name)s: %(message)s")
    # pymodbus writes a client gone mid-reply at ERROR with hex dumps of its frames: the simulated
    # PLCs' lines ended up in the controller's log at every e-stop (the controller's run does the same)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL if log_level.upper() != "DEBUG" else logging.DEBUG)
    cfg = load_config(config_path)
    if clock_path is not None:
        clock = elastic(clock_path, "sim")
    elif epoch_wall is None:
        clock = ScaledClock.starting(speed, epoch_farm)
    else:
        clock = ScaledClock(speed, epoch_wall, epoch_farm if epoch_farm is not None else epoch_wall)

    async def main():
        farm = SimFarm(cfg, clock, TruthLog(truth) if truth else None)
        farm.files_dir = Path(endpoints).parent     # the stereo rig's CALIB.json beside the endpoints
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        _stop_on_signals(loop, farm, stop)
        # SIGUSR1: the dispenser loses power and comes back (counters reset), as after a site power cut
        loop.add_signal_handler(signal.SIGUSR1, lambda: farm.dispenser and farm.dispenser.power_cycle())
        ears = None
        try:
            # a signal during start-up ends it there (it waited for every device up, then overran
            # SIM_STOP_S: exit 70 "stopping took longer than 1 s")
            starting = asyncio.create_task(farm.start())
            stopping = asyncio.create_task(stop.wait())
            await asyncio.wait((starting, stopping), return_when=asyncio.FIRST_COMPLETED)
            stopping.cancel()                     # (a start that failed leaves none pending either)
            if not starting.done():
                starting.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await starting
                return
            found = starting.result()
            tmp = Path(endpoints).with_suffix(".tmp")
            tmp.write_text(json.dumps(found, indent=2))
            os.replace(tmp, endpoints)            # readers never see half a file
            ears = DemandsHeard(hear, cfg.site, clock) if clock_path is not None and hear else None
            pacer = asyncio.create_task(_pace(farm, ears)) if clock_path is not None else None
            await stop.wait()
            if pacer is not None:
                pacer.cancel()
        finally:
            if ears is not None:
                ears.close()
            await farm.stop()

    asyncio.run(main())
    # a frame may still be rendering on a daemon thread (a survey pair takes a second and more):
    # the interpreter's finalization under it was seen to crash (SIGSEGV) or wait; nothing is left
    # to flush but the standard streams
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(0)


SIM_STOP_S = 1.0      # wall s from the first signal to the simulator's end at the latest


def _stop_on_signals(loop, farm, stop: asyncio.Event) -> None:
    """SIGINT, SIGTERM (what the controller sends, and PR_SET_PDEATHSIG when the controller dies)
    and SIGHUP end the simulator within SIM_STOP_S, whatever it is doing: the handler runs between
    any two bytecodes of the main thread, busy loop or not; it halts the pond's physics and the
    cameras at once, wakes the loop for the orderly stop (the truth log's closing records), and
    arms a watchdog that closes the truth log and ends the process if that stop overruns. Later
    signals change nothing: a SIGKILLed controller's threads each send one as they die."""
    from controller.shutdown import StopWatchdog, ignored_signals, wake_loop_on_signals

    def overrun() -> None:
        farm.halt()
        farm.truth.close(timeout_s=0.1)         # every record written is a whole line already

    watchdog = StopWatchdog(SIM_STOP_S, overrun, who="fishfarm sim")
    farm._signal_wakeup = wake_loop_on_signals(loop)

    def on_signal(signum, frame):
        watchdog.arm()
        farm.halt()
        with contextlib.suppress(RuntimeError):          # the loop has already closed
            loop.call_soon_threadsafe(stop.set)

    kept = ignored_signals()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        if sig not in kept:
            signal.signal(sig, on_signal)


def elastic(path: str, slot: str):
    """The elastic clock in ``path``, with this process's ``slot`` claimed (busy until it speaks)."""
    from controller.errors import BadInput
    from devices.elastic_clock import ElasticClock
    try:
        clock = ElasticClock(path)
    except (OSError, ValueError, BadInput) as exc:
        raise BadInput("--clock", None, str(exc)) from None
    try:
        clock.claim(slot)
    except BadInput as exc:
        clock.close()
        raise BadInput("--clock", None, str(exc)) from None
    # a clock file cut short while mapped: this process's own stop (SIGTERM: the controller's stop
    # path leaves the actuators safe), not the SIGBUS of reading the map past the file's end
    clock.on_lost = lambda: os.kill(os.getpid(), signal.SIGTERM)
    return clock


async def _pace(farm, ears=None) -> None:
    """Fish asking or not; a pond's cleaner is always busy (it moves by the tower camera's frames)."""
    from devices.sim.pace import pace
    if getattr(farm, "pond", None) is not None:
        farm.clock.busy()
        return
    await pace(farm.clock, list(farm.tanks.values()), heard=ears)


class DemandsHeard:
    """The farm time each tank's last demand was heard on the controller's bus (``farm/{site}/tank/
    {tank}/demand``): the simulator's pacer lets go of fish the controller has heard. A client
    session opened in a thread, retried while the controller is not up yet; until then nothing
    is heard and fish hold the clock for their whole attention span, as without it."""

    def __init__(self, connect: str, site: str, clock):
        self.connect, self.site, self.clock = connect, site, clock
        self.heard: dict[str, float] = {}
        self.session = self.sub = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._open, name="sim-hear-demands", daemon=True)
        self._thread.start()

    def __call__(self, tank: str) -> float:
        return self.heard.get(tank, -math.inf)

    def _open(self) -> None:
        from controller.zenoh_config import open_client
        session = open_client(self.connect, None, None, self._stop, "fishfarm sim --hear")
        if session is None:
            return
        self.session = session
        self.sub = session.declare_subscriber(f"farm/{self.site}/tank/*/demand", self._on_demand)

    def _on_demand(self, sample) -> None:
        # on Zenoh's thread: one dict store, read by the pacer on the loop
        self.heard[str(sample.key_expr).split("/")[3]] = self.clock.now()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        if self.session is not None:
            self.session.close()
