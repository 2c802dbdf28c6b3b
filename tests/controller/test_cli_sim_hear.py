"""``fishfarm sim --hear``: the simulator hears the controller's demands on its Zenoh endpoint."""
from __future__ import annotations

import math
import time

import zenoh

from controller.cli.sim_cmd import DemandsHeard
from tests.controller.zenoh_farm import free_port


class StillClock:
    def __init__(self, t: float):
        self.t = t

    def now(self) -> float:
        return self.t


def listening(endpoint: str) -> zenoh.Session:
    zc = zenoh.Config()
    for key, value in {"mode": '"peer"', "listen/endpoints": f'["{endpoint}"]', "connect/endpoints": "[]",
                       "scouting/multicast/enabled": "false", "scouting/gossip/enabled": "false"}.items():
        zc.insert_json5(key, value)
    return zenoh.open(zc)


def test_a_demand_put_for_a_tank_is_heard_at_the_farm_time_it_came():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    clock = StillClock(1_780_000_000.0)
    ears = DemandsHeard(endpoint, "demo", clock)     # before anyone listens: it keeps trying
    controller = listening(endpoint)
    try:
        assert ears("T3") == -math.inf
        deadline = time.monotonic() + 20.0
        while ears("T3") == -math.inf:            # put again until the subscriber is matched
            assert time.monotonic() < deadline, "the demand was never heard"
            controller.put("farm/demo/tank/T3/demand", b'{"t": "2026-05-28T20:26:40Z", "rate_hz": 0.5}')
            time.sleep(0.05)
        assert ears("T3") == clock.t
        clock.t += 600.0
        controller.put("farm/other/tank/T1/demand", b"{}")       # another site's tank: not ours
        controller.put("farm/demo/tank/T1/contact", b"{}")       # a contact is no demand
        controller.put("farm/demo/tank/T3/demand", b"{}")
        while ears("T3") != clock.t:
            assert time.monotonic() < deadline, "the second demand was never heard"
            time.sleep(0.01)
        assert ears("T1") == -math.inf
    finally:
        ears.close()
        controller.close()
