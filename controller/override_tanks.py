"""The operator commands about a tank's fish (``controller.overrides``): pause and resume its
feeding, survey it now, and the stock events (mortality, harvest, transfer) the rations count.
A mixin of ``Overrides``: its controller ``c``, ``_tank`` and ``_robot``.
"""
from __future__ import annotations

import logging

from controller.override_models import Loss, Refused, Tank, Transfer, parse, who

log = logging.getLogger("fishfarm.override")     # the overrides' logger, its one-line filter with it

NO_CAMERA = "no survey camera in this controller (farm.toml has no stereo_camera device)"


class TankCommands:
    async def pause(self, payload, by: str | None = None) -> dict:
        """A paused tank's demands are not served (closed as ``paused``), nor operator feeds; a
        portion already on its way finishes. Kept in the ledger: a restart stays paused."""
        cmd = parse(Tank, payload)
        self._tank(cmd.tank)
        fresh = self.c.store.pause_tank(cmd.tank, self.c.clock.now(), who(by, cmd.operator), cmd.reason)
        if self.c.robot is not None:
            self.c.robot.pause(cmd.tank)
        log.warning("pause %s by %s: %s", cmd.tank, by or cmd.operator, cmd.reason)
        return {"ok": True} if fresh else {"ok": True, "note": f"tank {cmd.tank} was paused already"}

    async def resume(self, payload, by: str | None = None) -> dict:
        cmd = parse(Tank, payload)
        self._tank(cmd.tank)
        was = self.c.store.resume_tank(cmd.tank)
        if self.c.robot is not None:
            self.c.robot.resume(cmd.tank)
        log.warning("resume %s by %s: %s", cmd.tank, by or cmd.operator, cmd.reason)
        return {"ok": True} if was else {"ok": True, "note": f"tank {cmd.tank} was not paused"}

    def _holds_fish(self, tank: str) -> None:
        """Refused when the tank's stock events took all its fish (harvested, moved out)."""
        if self.c.rations.stock(tank) <= 0:
            raise Refused(f"tank: {tank} holds no fish (its stock events took them all)")

    async def start_survey(self, payload, by: str | None = None) -> dict:
        """A weight survey of the tank now: the rail robot takes it once no demand waits, and leaves
        it for any demand that comes (controller/surveys/stop.py)."""
        cmd = parse(Tank, payload)
        self._tank(cmd.tank)
        self._robot()
        stops = getattr(self.c, "survey_stops", None)
        if stops is None:
            raise Refused(f"command: {NO_CAMERA}")
        if cmd.tank in self.c.store.paused_tanks():
            raise Refused(f"tank: {cmd.tank} is paused (resume it first)")
        self._holds_fish(cmd.tank)                # a visit would count nothing
        note = stops.request(cmd.tank)
        log.warning("start-survey %s by %s%s", cmd.tank, by or cmd.operator, f": {cmd.reason}" if cmd.reason else "")
        if note is None:      # asked: what will hold it back, said now (a bare ok read as "under way")
            robot, now = self._robot(), self.c.clock.now()
            ration = self.c.rations.today(cmd.tank, now)
            if robot.state == "estop":
                note = "asked for: it starts once the e-stop is reset"
            elif ration.source == "operator" and ration.grams == 0:
                note = f"asked for: {cmd.tank} is fasting today (an operator's 0 g ration): it waits for tomorrow"
        return {"ok": True} if note is None else {"ok": True, "note": note}

    async def mortality(self, payload, by: str | None = None) -> dict:
        return self._stock_event("mortality", parse(Loss, payload), None, by)

    async def harvest(self, payload, by: str | None = None) -> dict:
        return self._stock_event("harvest", parse(Loss, payload), None, by)

    async def transfer(self, payload, by: str | None = None) -> dict:
        cmd = parse(Transfer, payload)
        self._tank(cmd.tank)
        if cmd.to == cmd.tank:
            raise Refused("to: the same tank as tank")
        self._tank(cmd.to, "to")
        return self._stock_event("transfer", cmd, cmd.to, by)

    def _stock_event(self, kind: str, cmd, to: str | None, by: str | None) -> dict:
        """Fish that left ``cmd.tank`` (and, in a transfer, came to ``to``): the stock the rations
        use changes, and today's ration with it unless an operator or a survey set it."""
        self._tank(cmd.tank)
        rations, now = self.c.rations, self.c.clock.now()
        held = rations.stock(cmd.tank)
        if held <= 0:
            raise Refused(f"tank: {cmd.tank} holds no fish (its stock events took them all)")
        if cmd.count > held:
            raise Refused(f"count: more than the {held} fish in tank {cmd.tank}")
        self.c.store.add_stock_event(t=now, tank=cmd.tank, kind=kind, count=cmd.count, to_tank=to,
                                     who=who(by, cmd.operator), reason=cmd.reason)
        log.warning("%s %s %d fish%s by %s: %s", kind, cmd.tank, cmd.count, f" to {to}" if to else "",
                    by or cmd.operator, cmd.reason)
        stock = {}
        for tank in filter(None, (cmd.tank, to)):
            rations.restocked(tank, now)
            self.c.publish_ration(tank)
            stock[tank] = rations.stock(tank)
        return {"ok": True, "stock": stock}
