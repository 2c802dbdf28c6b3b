"""The controller assembled in-process, its simulated devices in a child ``fishfarm sim``, driven by
an operator over real Zenoh: status, refusals, an e-stop with an unreadable payload, a manual feed."""
import asyncio
import json
import tomllib

import tomli_w

from controller.app import Controller
from controller.bus import Bus
from controller.config import load_config
from devices.clock import ScaledClock
from hil_tests.farm import without_cleaner  # the demo farm's feeder alone
from hil_tests.ports import free_port


def test_operator_drives_the_controller_over_zenoh(tmp_path):
    port = free_port()
    raw = without_cleaner(tomllib.loads(open("config/farm.toml").read()))
    raw["scada"]["port"] = 0    # any free port: runs must not collide with the demo's 5020
    raw["bus"] = {"listen": [f"tcp/127.0.0.1:{port}"]}
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    cfg = load_config(tmp_path / "farm.toml")

    async def main():
        controller = Controller(cfg, ScaledClock.starting(50.0))
        await controller.start()
        client = Bus.client(f"tcp/127.0.0.1:{port}")

        def ask(suffix, payload=None):
            return asyncio.to_thread(client.query, suffix, payload)

        async def until(predicate, what, wall_s=20.0):
            for _ in range(int(wall_s / 0.01)):
                if predicate():
                    return
                await asyncio.sleep(0.01)
            raise AssertionError(f"timed out: {what}; feeder {controller.robot.state}")

        try:
            await until(lambda: controller.robot.state == "idle", "homed")
            [status] = await ask("status")
            assert sorted(status["tanks"]) == [f"T{i}" for i in range(1, 9)]
            assert status["feeder"]["state"] == "idle"
            [reply] = await ask("override/nope", {})
            assert reply["ok"] is False and "unknown command" in reply["error"]
            [reply] = await ask("override/feed", {"tank": "T9", "grams": 5})
            assert reply == {"ok": False, "error": "tank: no tank 'T9'"}
            [reply] = await ask("override/feed", {"tank": "T1", "grams": -5})
            assert reply["ok"] is False and reply["error"].startswith("grams:")
            # an e-stop is never refused, even when its payload cannot be read
            replies = await asyncio.to_thread(
                lambda: [json.loads(r.ok.payload.to_string()) for r in
                         client.session.get("farm/demo/override/estop", payload=b"\xff{oops", timeout=2)])
            assert replies == [{"ok": True, "confirmed": True}]
            assert controller.robot.state == "estop" and "estop" in controller.alarms.active
            [reply] = await ask("override/feed", {"tank": "T1", "grams": 20})
            assert reply["ok"] is False and "estop" in reply["error"]
            [reply] = await ask("override/reset", {"operator": "ana", "reason": "rail checked"})
            assert reply == {"ok": True}
            await until(lambda: controller.robot.state == "idle", "idle after reset")
            [reply] = await ask("override/feed", {"tank": "T1", "grams": 20, "operator": "ana"})
            assert reply["ok"] is True and reply["grams"] == 20.0 and isinstance(reply["demand"], int)
            await until(lambda: any(f.source == "operator" and f.phase == "done"
                                    for f in controller.store.feeds()), "operator's portion dispensed")
            feed = next(f for f in controller.store.feeds() if f.source == "operator")
            assert feed.tank == "T1" and feed.target_g == 20.0 and 15.0 < feed.grams < 25.0
        finally:
            client.close()
            await controller.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


def test_waits_for_absent_devices_yet_answers_and_estops(tmp_path):
    port, dead_port = free_port(), free_port()
    raw = without_cleaner(tomllib.loads(open("config/farm.toml").read()))
    raw["scada"]["port"] = 0    # any free port: runs must not collide with the demo's 5020
    raw["bus"] = {"listen": [f"tcp/127.0.0.1:{port}"]}
    raw["store"] = {"path": str(tmp_path / "ledger.db")}
    raw["devices"] = {
        "contacts": {"kind": "contacts", "driver": "serial", "port": str(tmp_path / "no-hub")},
        "rail": {"kind": "rail", "driver": "can", "interface": "slcan", "channel": str(tmp_path / "no-can")},
        "dispenser": {"kind": "dispenser", "driver": "modbus", "port": dead_port, "timeout_s": 0.2},
    }
    raw.pop("sim")
    (tmp_path / "farm.toml").write_text(tomli_w.dumps(raw))
    controller = Controller(load_config(tmp_path / "farm.toml"), ScaledClock.real())

    async def main():
        running = asyncio.create_task(controller.run())
        client = None
        try:
            for _ in range(500):
                if getattr(controller, "overrides", None) is not None and len(controller.alarms.active) == 3:
                    break
                await asyncio.sleep(0.01)
            client = Bus.client(f"tcp/127.0.0.1:{port}")
            [status] = await asyncio.to_thread(client.query, "status")
            assert status["feeder"]["state"] == "starting"
            assert {a["source"] for a in status["alarms"]} == {"device/contacts", "device/rail",
                                                                 "device/dispenser"}
            [reply] = await asyncio.to_thread(client.query, "override/feed", {"tank": "T1", "grams": 10})
            assert reply["ok"] is False and "starting" in reply["error"]
            [reply] = await asyncio.to_thread(client.query, "override/estop", {})
            # no device to latch: the stop is recorded, the reply says the latches are unconfirmed
            assert reply == {"ok": True, "confirmed": False} and controller.estop_before_start is not None
            # the alarm names the devices whose latches are not confirmed, as it does once feeding
            for _ in range(300):
                [status] = await asyncio.to_thread(client.query, "status")
                [estop] = [a for a in status["alarms"] if a["source"] == "estop"]
                if "not confirmed by" in estop["text"]:
                    break
                await asyncio.sleep(0.01)
            assert "dispenser (" in estop["text"] and "drive (" in estop["text"], estop["text"]
            # the feeder is in e-stop, though starting: the robot will start in it (SCADA's coil 0 and
            # discrete input 0 read 0 under the standing e-stop alarm)
            assert status["feeder"]["state"] == "estop" and status["feeder"]["starting"] is True
            assert not running.done()                       # still waiting, not dead
        finally:
            if client is not None:
                client.close()
            controller.stopping.set()
            await asyncio.wait_for(running, 10)

    asyncio.run(asyncio.wait_for(main(), 30))
