"""controller.feeding.dispensing: the room a portion capped by the ration leaves for the auger."""
import asyncio
from statistics import NormalDist, fmean, pstdev

import pytest

from controller.feeding.dispensing import MEASURED, OVERSHOOT, UNMEASURED
from tests.controller.feeding.rig import rig


def run(coro):
    return asyncio.run(coro)


def _history(r, ratios, aim_g=200.0):
    """Measured runs in the ledger (an earlier day: today's ration untouched), each delivering
    ``ratio`` x what it aimed at: what an auger of that spread leaves behind."""
    t = r.clock.now() - 30 * 86400.0
    for k, ratio in enumerate(ratios):
        f = r.store.add_intent(tank="T2", date="2026-01-01", t=t + k, target_g=aim_g, run_s=aim_g / 12.0,
                               cycles_before=k, source="demand")
        r.store.close_feed(f.id, "done", aim_g * ratio, t + k + 20.0, note=MEASURED)


def _spread(sd, n=200):
    """n deliveries / aims of an auger with that spread: the normal's quantiles at evenly spaced
    probabilities (the worst of 200 ~2.8 sd above the mean)."""
    return [1.0 + sd * NormalDist().inv_cdf((k + 0.5) / n) for k in range(n)]


@pytest.mark.parametrize("sd", [0.045, 0.06, 0.08])
def test_a_capped_portion_leaves_room_for_every_delivery_the_auger_has_shown(tmp_path, sd):
    async def main():
        async with rig(tmp_path, run=False) as r:
            ratios = _spread(sd)
            _history(r, ratios)
            robot = r.new_robot()                         # a restart: the spread read from the ledger
            r.rations.set("T1", r.clock.now(), 40.0, "operator")       # less than a 60 g portion
            portion = robot.dispensing.portion("T1")
            left = r.rations.today("T1", r.clock.now()).left_g
            assert 0 < portion < left                     # the ration caps it
            # the worst delivery seen, and one 6 measured sd above the measured mean, still keep the
            # tank within its ration
            assert portion * max(ratios) <= left
            assert portion * (fmean(ratios) + 6 * pstdev(ratios)) <= left * (1 + 1e-9)
            # (a fixed 15 % left room for ~3 sd: at sd 0.06 the worst of 200 runs, +17 %, overfed)
    run(main())


def test_a_steady_auger_keeps_the_least_room_and_an_unmeasured_one_the_most(tmp_path):
    async def main():
        async with rig(tmp_path, run=False) as r:
            assert r.new_robot().dispensing.overshoot == UNMEASURED      # no run measured yet
            _history(r, _spread(0.01, 5))
            assert r.new_robot().dispensing.overshoot == OVERSHOOT       # too few runs for a spread
            _history(r, _spread(0.01))
            assert r.new_robot().dispensing.overshoot == OVERSHOOT       # 6 sd = 6 %: the floor holds
            _history(r, _spread(0.2))
            assert r.new_robot().dispensing.overshoot == UNMEASURED      # never more room than a guess's
    run(main())
