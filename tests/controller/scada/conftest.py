"""A SCADA server in a thread of its own (its own event loop), in front of a stand-in controller
whose status the test sets and whose overrides are recorded."""
from __future__ import annotations

import asyncio
import csv
import logging
import threading
from pathlib import Path

import pytest

from controller.config import load_config
from controller.scada.service import Scada

ROOT = Path(__file__).resolve().parents[3]
MAP_CSV = ROOT / "config" / "modbus_map.csv"


def map_rows() -> list[dict]:
    with open(MAP_CSV, newline="") as fh:
        return list(csv.DictReader(fh))


class StandIn:
    """What the server needs of the controller: status(), trip_estop(), overrides.apply()."""

    def __init__(self, status: dict | None = None, refuse: set[str] = frozenset()):
        self.current = status or {"t": "2026-06-01T00:00:00.000Z", "feeder": {"state": "idle"}, "tanks": {},
                                  "alarms": []}
        self.trips: list[str] = []
        self.calls: list[tuple] = []
        self.refusals: list[tuple] = []      # writes the map refused, as audited
        self.notes: list[tuple] = []         # writes answered without an override, as audited
        self.refuse = set(refuse)
        self.overrides = self

    def status(self) -> dict:
        return self.current

    def trip_estop(self, reason: str) -> None:
        self.trips.append(reason)

    def refused_on_wire(self, command, error, user=None, payload=None, *, origin="zenoh") -> None:
        self.refusals.append((command, error, user, payload, origin))

    def noted(self, command, payload, reply, *, user=None, origin="zenoh") -> None:
        self.notes.append((command, payload, reply, user, origin))

    async def apply(self, command, payload, *, user=None, origin="zenoh") -> dict:
        self.calls.append((command, payload, user, origin))
        if command in self.refuse:
            return {"ok": False, "error": f"{command}: refused by the stand-in"}
        return {"ok": True}


class ServerThread:
    def __init__(self, controller: StandIn, **scada):
        cfg = load_config(ROOT / "config" / "farm.toml")
        self.cfg = cfg.model_copy(update={"scada": cfg.scada.model_copy(update={"port": 0, **scada})})
        self.controller = controller
        self.loop = asyncio.new_event_loop()
        self.ready = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        assert self.ready.wait(10), "the SCADA server did not start"

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)

        async def main():
            self.scada = Scada(self.controller, self.cfg)
            self.task = asyncio.create_task(self.scada.run())
            await self.scada.listening.wait()
            self.port = self.scada.server.port
            self.ready.set()
            try:
                await self.task
            except asyncio.CancelledError:
                pass

        self.loop.run_until_complete(main())

    def call(self, fn, *args):
        """Run fn on the server's loop and wait for it."""
        async def run():
            return fn(*args)
        return asyncio.run_coroutine_threadsafe(run(), self.loop).result(10)

    def refresh(self) -> None:
        self.call(self.scada.coordinator.refresh)

    def stop(self) -> None:
        self.loop.call_soon_threadsafe(self.task.cancel)
        self.thread.join(10)


@pytest.fixture
def serve():
    # as `fishfarm run` sets it (controller/cli/run_cmd.py): pymodbus's error lines carry hex dumps of
    # the last frames, which a garbage-sending client would otherwise have the server format for it
    pymodbus_log = logging.getLogger("pymodbus")
    level = pymodbus_log.level
    pymodbus_log.setLevel(logging.CRITICAL)
    servers = []

    def start(controller: StandIn | None = None, **scada) -> ServerThread:
        srv = ServerThread(controller or StandIn(), **scada)
        servers.append(srv)
        return srv

    yield start
    for srv in servers:
        srv.stop()
    pymodbus_log.setLevel(level)
