"""``fishfarm worker``: a vision worker measuring stereo pairs for the farm's surveys over Zenoh.

    fishfarm worker [--connect tcp/127.0.0.1:7447] [--site demo] [--config farm.toml]
                    [--id NAME] [--cpu 0[,1...]] [--user U --password P] [--duration S]

It connects as a Zenoh client (no listening, no scouting) to the controller, a router, or a
``fishfarm survey --workers ENDPOINT`` listening there, waiting and retrying while nobody does, and
serves until SIGINT/SIGTERM/SIGHUP (or ``--duration``). ``--config``: site and endpoint from farm.toml's
``[bus]`` (its first listen endpoint). ``--cpu`` pins the process to those cores
(``os.sched_setaffinity``): one worker per core is how to hold each to one. Keys and job format:
controller/surveys/worker.py and wire.py, README "Vision workers".
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")          # before numpy loads: a worker is one thread of maths

import re  # noqa: E402
import signal  # noqa: E402
import socket  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402

import click  # noqa: E402

from controller.cli.params import Finite  # noqa: E402
from controller.errors import BadInput  # noqa: E402

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
_ID = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


def _cpus(text: str | None) -> set[int] | None:
    if text is None:
        return None
    try:
        cpus = {int(x) for x in text.split(",") if x.strip()}
    except ValueError:
        raise BadInput("--cpu", None, f"expected core numbers like 0 or 0,1, got {text!r}") from None
    have = os.sched_getaffinity(0)
    if not cpus or not cpus <= have:
        raise BadInput("--cpu", None, f"cores {sorted(cpus)} not all available (this process may use {sorted(have)})")
    return cpus


def _from_config(path: str, connect: str | None, site: str | None) -> tuple[str | None, str | None]:
    from controller.config import load_config
    cfg = load_config(path)
    if connect is None:
        if not cfg.bus.listen:
            raise BadInput(path, "bus.listen", "empty: give --connect")
        connect = cfg.bus.listen[0]
    return connect, site or cfg.site


@click.command()
@click.option("--connect", default=None, metavar="tcp/HOST:PORT",
              help=f"Zenoh endpoint of the controller or a router [default: {DEFAULT_CONNECT}, or farm.toml's]")
@click.option("--site", default=None, help="farm site [default: demo, or farm.toml's]")
@click.option("--config", "config_path", default=None, metavar="farm.toml", help="take site and endpoint from here")
@click.option("--id", "worker_id", default=None, help="this worker's name on the bus [default: HOST-PID]")
@click.option("--cpu", "cpu", default=None, metavar="0[,1...]", help="pin to these CPU cores")
@click.option("--user", default=None, help="Zenoh user name (deployments with authentication)")
@click.option("--password", default=None, help="Zenoh password")
@click.option("--duration", type=Finite(min=0), default=None, help="serve this many seconds, then stop")
@click.option("--measure", default=None, hidden=True, help="module:function measuring a pair (tests)")
def worker(connect, site, config_path, worker_id, cpu, user, password, duration, measure):
    """Serve stereo-pair measurements to the farm's surveys (Zenoh queryable)."""
    if config_path:
        connect, site = _from_config(config_path, connect, site)
    connect, site = connect or DEFAULT_CONNECT, site or "demo"
    if not _ID.match(site):
        raise BadInput("--site", None, f"{site!r}: letters, digits, _ and - only")
    if worker_id is None:                     # a host's name is cleaned: it is not the user's word
        worker_id = re.sub(r"[^A-Za-z0-9_.-]", "-", f"{socket.gethostname()}-{os.getpid()}")[:64]
    elif not _ID.match(worker_id):            # cleaned silently before: 'a/b*' served as 'a-b-'
        raise BadInput("--id", None, f"{worker_id!r}: 1 to 64 letters, digits, '.', '_' and '-'")
    cores = _cpus(cpu)
    if cores is not None:
        os.sched_setaffinity(0, cores)

    import cv2

    from controller.surveys.runner import MEASURE
    from controller.surveys.worker import Worker
    cv2.setNumThreads(1)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(sig) != signal.SIG_IGN:     # a background job's SIGINT, nohup's SIGHUP
            signal.signal(sig, lambda *_: stop.set())
    if duration is not None:
        timer = threading.Timer(duration, stop.set)
        timer.daemon = True
        timer.start()
    from controller.zenoh_config import open_client
    session = open_client(connect, user, password, stop, "fishfarm worker")
    if session is None:
        return 0
    served = None
    try:
        served = Worker(session, site, worker_id, measure or MEASURE)
        served.start()
        where = f" on cores {sorted(cores)}" if cores else ""
        click.echo(f"fishfarm worker {worker_id}: serving farm/{site}/worker/node/{worker_id}/pair "
                   f"via {connect}{where}", err=True)
        sys.stderr.flush()
        started = time.monotonic()
        served.serve(stop)
        click.echo(f"fishfarm worker {worker_id}: {served.served} pairs in "
                   f"{time.monotonic() - started:.1f} s of serving (after connecting), stopping", err=True)
    finally:
        if served is not None:
            served.close()
        session.close()
    return 0
