"""The survey stops of the rail robot wired from the config: the stereo camera device, the
schedule (controller/surveys/schedule.py) and the stop itself (controller/surveys/stop.py).

The robot sees one object (``robot.surveys``): ``next`` (the survey to work on, or None) and
``visit`` (the stop at the tank). Operators reach ``request`` through ``start-survey``.
"""
from __future__ import annotations

import logging

import zenoh

from controller.errors import BadInput
from controller.ledger_writes import LedgerUnwritable
from controller.surveys.schedule import SurveySchedule
from controller.surveys.stop import SurveySession, SurveyStop

log = logging.getLogger("fishfarm.survey")

WORKERS_DISCOVER_S = 0.3   # wall: how long a pair waits to hear of a worker before it is measured here


def survey_camera_name(cfg) -> str | None:
    """The stereo camera the robot carries: ``[surveys] camera``, else the only one; None when the
    farm has none (surveys then come from ``fishfarm survey --tank`` only). BadInput otherwise."""
    cameras = [name for name, s in cfg.devices.items() if s["kind"] == "stereo_camera"]
    name = cfg.surveys.camera
    if name is not None:
        if name not in cameras:
            raise BadInput(cfg.path, "surveys.camera", f"no stereo_camera device {name!r} "
                                                       f"(stereo cameras: {', '.join(cameras) or 'none'})")
        return name
    if len(cameras) > 1:
        raise BadInput(cfg.path, "surveys.camera", f"{len(cameras)} stereo cameras: name the robot's")
    if not cameras and any(t.survey is not None for t in cfg.tanks):
        tank = next(i for i, t in enumerate(cfg.tanks) if t.survey is not None)
        raise BadInput(cfg.path, f"tanks.{tank}.survey", "scheduled surveys need a stereo_camera device")
    return cameras[0] if cameras else None


class SurveyStops:
    def __init__(self, cfg, clock, camera, store, rations, alarms, species, **kw):
        self.schedule = SurveySchedule(cfg, store, rations, clock)
        self.stop = SurveyStop(cfg, clock, camera, store, species, alarms, **kw)
        self.clock = clock
        self.poke = lambda: None               # the robot's wake-up, set by the wiring

    def next(self, paused: set[str], now: float) -> SurveySession | None:
        session = self.schedule.next(paused, now)
        if session is None:                    # nothing to survey now: the cameras need not stream
            self.stop.release()
        return session

    async def visit(self, session: SurveySession, interrupted, wake) -> str:
        outcome = "failed"
        try:
            outcome = await self.stop.visit(session, interrupted, wake)
        except Exception as exc:       # a bug in a survey never stops the feeding: alarmed, dropped
            if isinstance(exc, LedgerUnwritable):     # the ledger alarm stands: no traceback
                log.warning("survey of %s not recorded: the ledger cannot be written", session.tank)
            else:
                log.exception("survey of %s failed", session.tank)
            session.failed = f"internal error: {type(exc).__name__}: {exc}"
            self.stop.alarms.raise_("survey", f"survey of {session.tank} failed: {session.failed}", "warning",
                                    kind="failed")
        finally:
            self.schedule.ended(session, outcome if outcome != "failed" or session.failed else "preempted",
                                self.clock.now())
        if outcome == "captured":
            self.stop.finish(session).add_done_callback(lambda _task: self._recorded(session))
        return outcome

    def _recorded(self, session: SurveySession) -> None:
        self.schedule.recorded(session, self.clock.now())
        self.poke()

    def request(self, tank: str, pairs: int | None = None) -> str | None:
        note = self.schedule.request(tank, pairs)
        self.poke()
        return note

    def snapshot(self) -> dict:
        cur = self.schedule.current
        held = None if cur is None else self.schedule.held(cur.tank, set(self.schedule.store.paused_tanks()),
                                                           self.clock.now())
        # "held": why an unfinished survey waits (its tank paused, fasting, emptied), or None: an
        # operator read a survey held by a pause as one under way
        return {"current": None if cur is None else {"tank": cur.tank, "pairs": cur.pairs, "captured": cur.captured,
                                                     "fish": len(cur.lengths), "visits": cur.visits, "why": cur.why,
                                                     "held": held},
                "asked": list(self.schedule.asked)}

    async def close(self) -> None:
        await self.stop.close()


def workers_or_here(session, site: str, discover_s: float = WORKERS_DISCOVER_S):
    """The survey stop's ``measure``: the farm's vision workers (``fishfarm worker``, reached over
    the controller's own Zenoh session, controller/surveys/remote.py) measure its pairs when any is
    up; with none, this process does, as before. ``measure.in_flight()``: the pairs the stop may
    have measuring at once — what the workers up take (``PER_WORKER`` each), at least the stop's
    own ``IN_FLIGHT``: with two workers and two pairs in flight, frames the camera streamed while
    the stop waited were rendered for nothing (~40 % of a grow-out's). A worker one pair's dispatch
    drops is benched for the pairs after it (``remote.BENCH_S``), unless its token comes again (a
    restarted worker is used at once)."""
    from controller.surveys.remote import PER_WORKER, measure_remote
    from controller.surveys.stop import IN_FLIGHT
    from controller.surveys.worker import node_key

    prefix, live, benched = node_key(site, ""), set(), {}

    def on_token(sample) -> None:
        worker = str(sample.key_expr)[len(prefix):]
        (live.add if sample.kind == zenoh.SampleKind.PUT else live.discard)(worker)
        if sample.kind == zenoh.SampleKind.PUT:
            benched.pop(worker, None)

    def measure(jobs, calib, setup):
        return measure_remote(jobs, calib, setup, session=session, site=site, discover_s=discover_s,
                              local_workers=1, announce=False, known=live.copy, benched=benched)
    measure.in_flight = lambda: max(IN_FLIGHT, PER_WORKER * len(live))
    measure.tokens = session.liveliness().declare_subscriber(f"{prefix}*", on_token, history=True)
    return measure


def build_survey_stops(controller) -> SurveyStops | None:
    """For the app: the robot's survey stops, or None when the farm has no stereo camera."""
    from controller.surveys.species import survey_species
    c = controller
    name = survey_camera_name(c.cfg)
    if name is None:
        return None
    kinds = {sp: survey_species(sp) for sp in {t.species for t in c.cfg.tanks}}
    stops = SurveyStops(c.cfg, c.clock, c.devices[name], c.store, c.rations, c.alarms,
                        {t.id: kinds[t.species] for t in c.cfg.tanks},
                        measure=workers_or_here(c.bus.session, c.cfg.site))
    stops.poke = c.robot.poke
    return stops
