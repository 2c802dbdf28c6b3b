"""The SCADA face as one part of the controller: the map for this farm, the coordinator, the guard
and the server, started and stopped with the controller (controller/app.py). The server runs on a
thread of its own (controller/scada/serving.py); the coordinator's refresh, the guard's writes and
the alarms run on the controller's loop."""
from __future__ import annotations

import asyncio
import contextlib
import logging
import sys

from controller.scada.guard import Guard
from controller.scada.register_map import layout
from controller.scada.server import ScadaServer, ScadaStore
from controller.scada.serving import STOP_WAIT_S, ServingThread
from controller.scada.snapshot import Coordinator, refreshing

log = logging.getLogger("fishfarm.scada")
LISTEN_BACKOFF_S = (1.0, 2.0, 5.0, 10.0, 30.0)
SWITCH_INTERVAL_S = 0.001


class Scada:
    def __init__(self, controller, cfg, *, alarms=None):
        self.cfg, self.scada = cfg, cfg.scada
        self.controller = controller
        self.alarms = alarms
        self.lay = layout(cfg)
        self.coordinator = Coordinator(controller.status, self.lay, self.scada)
        self.guard = Guard(self.lay, cfg, self.scada, controller, self.coordinator)
        self.store = ScadaStore(self.lay, self.scada, self.coordinator, self.guard)
        self.server: ScadaServer | None = None
        self.serving: ServingThread | None = None
        self.listening = asyncio.Event()

    async def listen(self) -> bool:
        """On the serving thread's loop (the server's transport and futures belong to it)."""
        server = ScadaServer(self.store, self.scada, self.cfg.site)
        server.urgent = lambda: self.controller.trip_estop(f"modbus e-stop by {self.scada.identity}")
        if not await server.listen():
            return False
        self.server = server
        log.info("scada: Modbus TCP on %s:%s, unit %d, %s-endian words%s", self.scada.listen, server.port,
                 self.scada.unit, self.scada.word_order, ", read only" if self.scada.read_only else "")
        return True

    async def run(self) -> None:
        """Listen (retrying: a port still held by the previous run frees itself; a SCADA that cannot
        connect is an alarm, not a reason to stop feeding), then refresh the snapshot and drop idle
        connections until cancelled."""
        # pollers keep the loop's thread busy; at Python's 5 ms switch interval the e-stop lane and
        # Zenoh's e-stop thread wait up to that for the GIL at every step of their sends (measured
        # under 4 flat-out pollers: Zenoh e-stop p50 5.1 ms at 5 ms, 2.5 ms at 0.5 ms)
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        self.serving = ServingThread()
        self.store.act_loop = asyncio.get_running_loop()
        try:
            attempt = 0
            while not await self.serving.run(self.listen()):
                if attempt == 0 and self.alarms is not None:
                    self.alarms.raise_("scada", f"cannot listen on {self.scada.listen}:{self.scada.port} "
                                                "(address in use, or not this machine's)", kind="listen")
                await asyncio.sleep(LISTEN_BACKOFF_S[min(attempt, len(LISTEN_BACKOFF_S) - 1)])
                attempt += 1
            if attempt and self.alarms is not None:
                self.alarms.clear("scada", "listening", kind="listen")
            self.listening.set()
            await asyncio.gather(refreshing(self.coordinator, self.scada.refresh_s),
                                 self.serving.run(self.server.watch_idle()))
        finally:
            await self.close()

    async def close(self) -> None:
        server, self.server = self.server, None
        serving, self.serving = self.serving, None
        self.listening.clear()
        if serving is None:
            return
        if server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(serving.run(server.shutdown()), STOP_WAIT_S)
        await serving.close()


__all__ = ["Scada"]
