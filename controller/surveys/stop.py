"""The rail robot's survey stop: at the tank, wait for the water to settle, capture stereo pairs
until ``pairs`` are in or the mean weight's 95 % CI is within ±``ci_pct`` (``[surveys]``), measure
them, record the survey in the ledger (SurveyWatch then replans the ration).

A stop never holds a feeding demand back: a visit captures one pair at a time and leaves as soon
as a demand is waiting (``interrupted``) — from the settle wait, from a wait for a frame, between
pairs. The survey (``SurveySession``) outlives the visit: the robot comes back, lets the water
settle again and captures the rest. Pairs are measured off the loop (a thread each, at most
``IN_FLIGHT`` at once, or ``measure.in_flight()`` when the measuring is elsewhere: vision workers)
while the next is captured; measuring the last ones needs no robot, so the
robot is free once the last pair is captured, and the survey is recorded when they are measured.

Measuring goes through ``measure_pairs`` only: same shape as ``runner.measure_all`` (jobs, calib,
setup -> results in order), the one place remote vision workers plug in.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controller.surveys.frames import PairJob
from controller.surveys.outputs import fish_entry
from controller.surveys.runner import PairResult, measure_all
from devices.errors import BadInput, DeviceError, DeviceFault, DeviceTimeout
from vision.survey_stats import implausible, summarise

log = logging.getLogger("fishfarm.survey")
IN_FLIGHT = 2              # pairs measuring at once here: the robot's own CPU stays free for the loop
Z95 = 1.96
# Backstops, wall seconds, for waits each bounded below them (a camera's open and read timeouts, a
# vision worker's 30 s): a wait that outlives one anyway (a hung driver, a lost thread) fails the
# visit, alarmed and retried, or leaves its pair out, logged, instead of holding the robot at the
# tank for good (a probe saw a survey hold it two farm days, every other tank's survey behind it)
START_WALL_S = 60.0
MEASURE_WALL_S = 120.0
# A visit is cut short once ``probe_pairs`` are measured if its fish come at under this share of the
# rate that weighs the tank (``min_weighed_fish`` in the session's pairs): it would end with too few
# fish anyway, be recorded as such and tried again. Measured on 1,105 grow-out visits (14 runs,
# 960x720, up to 32 pairs): of the 99 that ended under 10 fish (the water hid them: a reef behind),
# 90 are caught after 8 pairs, most with 0-1 fish; 5 of the 1,006 that weighed their tank would
# have been cut (and tried again); 8 % of all pairs are saved. At 0.3: 78 caught, 1 cut; at 0.7:
# 95 caught, 8 cut
HOPELESS_SHARE = 0.5


def measure_pairs(jobs: Iterable[PairJob], calib, setup) -> Iterator[PairResult]:
    """Every pair measured, in order: the survey stop's one call into the vision (here, in this
    process; remote vision workers take the same arguments)."""
    return measure_all(jobs, calib, setup, workers=1)


@dataclass
class SurveySession:
    """One survey of one tank, across visits. ``why``: schedule | operator."""

    tank: str
    pairs: int
    why: str
    t: float                                   # when it was asked for
    began: float | None = None                 # when its first visit reached the tank: its time in the ledger
    captured: int = 0
    last_pair_t: float = -math.inf
    lengths: list[float] = field(default_factory=list)
    entries: list[dict] = field(default_factory=list)
    measuring: dict = field(default_factory=dict)            # task -> (frame, loop time it began)
    visits: int = 0
    failed: str | None = None
    unfit: str | None = None                   # a pair's frames the calibration cannot take: the camera's fault
    rejected: list[float] = field(default_factory=list)      # lengths left out as measuring errors
    measured: int = 0                          # pairs measured, with fish or none (a pair that failed: not)
    cut_short: str | None = None               # why its capture ended before ``pairs`` (SurveyStop.hopeless)

    def precise(self, weight, ci_pct: float, min_fish: int) -> bool:
        """The mean weight's 95 % CI (normal approximation) within ±ci_pct of it, over the lengths
        the record will keep: one wild length (an 18 cm among 10 cm fish), which the record leaves
        out as a measuring error, held a survey at its tank for 80 pairs where 18 had sufficed."""
        measured = np.asarray(self.lengths, float)
        kept = measured[~implausible(measured)]
        n = len(kept)
        if n < max(min_fish, 2):
            return False
        w = weight.weight_g(kept)
        return Z95 * float(np.std(w, ddof=1)) / math.sqrt(n) <= ci_pct / 100 * float(np.mean(w))


class SurveyStop:
    """What the robot calls at a tank (``visit``), and the sessions' bookkeeping."""

    def __init__(self, cfg, clock, camera, store, species, alarms, *, measure: Callable = measure_pairs):
        self.cfg, self.s = cfg, cfg.surveys
        self.clock, self.camera, self.store, self.alarms = clock, camera, store, alarms
        self.species, self.measure = species, measure          # tank -> SurveySpecies
        # pairs measuring at once: measured here, IN_FLIGHT; by vision workers, as many as they take
        # (2 each): the stream's frames are taken as they come instead of rendered and dropped
        self.in_flight = getattr(measure, "in_flight", lambda: IN_FLIGHT)
        self.setups = {tank: sp.setup(self.s.setup, None, self.s.floor_mm) for tank, sp in species.items()}
        self._power: asyncio.Future | None = None          # the cameras' last start or stop, in order
        self._waiting: tuple | None = None                  # (kind, task, the one before) not begun yet
        # measuring threads of their own: the default executor's few (the cameras' opens and closes
        # run there) are never all held by pairs a slow worker has
        self.pool = ThreadPoolExecutor(max_workers=8, thread_name_prefix="survey-measure")
        self.start_wall_s, self.measure_wall_s = START_WALL_S, MEASURE_WALL_S
        self.finishing: set[asyncio.Task] = set()
        self.recorded: list[int] = []                      # survey ids, in order

    def enough(self, session: SurveySession) -> bool:
        # never precise on fewer fish than weigh the tank: a min_weighed_fish over what the CI stop
        # left (100 against ~63) made every survey a few-fish one, retried hourly, for good
        least = max(self.s.min_fish, self.s.min_weighed_fish)
        return (session.captured >= session.pairs or self.hopeless(session)
                or session.precise(self.species[session.tank].weight, self.s.ci_pct, least))

    def hopeless(self, session: SurveySession) -> bool:
        """The visit's fish so far come too slowly to weigh the tank in its pairs (``HOPELESS_SHARE``):
        the water hides them (turbid, a reef behind, the lights, a fouled lens). Its capture ends
        there, and the survey is recorded with what it counted: one of too few fish, warned of and
        tried again (SurveyWatch, the schedule): in the grow-out, 22-23 of its 32 pairs sooner. Once
        cut, it stays cut (pairs still measuring may add a fish or two)."""
        if session.cut_short is not None:
            return True
        measured, probe = session.measured, self.s.probe_pairs
        if probe <= 0 or measured < probe:
            return False
        need = HOPELESS_SHARE * self.s.min_weighed_fish * measured / session.pairs
        if len(session.lengths) >= need:
            return False
        session.cut_short = (f"{len(session.lengths)} fish in its first {measured} pairs measured, under half "
                             f"the rate that weighs the tank ({self.s.min_weighed_fish} fish in {session.pairs} "
                             "pairs)")
        log.info("survey of %s cut short: %s", session.tank, session.cut_short)
        return True

    async def visit(self, session: SurveySession, interrupted: Callable[[], bool], wake: asyncio.Event) -> str:
        """At the tank: ``captured`` (all in: the robot may go), ``preempted`` (a demand waits; the
        session resumes later) or ``failed`` (the camera: the session is dropped, alarmed).

        The cameras stream for the visit only, from the carriage's arrival: a frame taken on the way
        is never measured as this tank's fish. Frames wait in a network camera's buffers, so the
        first ``stale_frames`` that arrive after the water settled are dropped as well."""
        session.visits += 1
        if session.began is None:
            session.began = self.clock.now()
        outcome = "failed"
        settled_at = self.clock.now() + self.s.settle_s
        try:
            opening = self._chain(self.camera.start)       # after the last stop; it may take seconds
            until = asyncio.get_running_loop().time() + self.start_wall_s
            while not opening.done():
                try:
                    left = until - asyncio.get_running_loop().time()
                    await _first(asyncio.wait_for(asyncio.shield(opening), max(left, 0.0)), wake)
                except TimeoutError:
                    raise DeviceTimeout(self.camera.name,
                                        f"the cameras did not start within {self.start_wall_s:g} s") from None
                # woken by what is no demand (an operator's start-survey on the way here): wait on;
                # the visit had ended at once and the cameras opened twice in a second
                if not opening.done() and interrupted():
                    outcome = "preempted"
                    return outcome
            opening.result()
            while self.clock.now() < settled_at:
                if interrupted():
                    outcome = "preempted"
                    return outcome
                await _until(self.clock, wake, settled_at - self.clock.now())
            stale = self.s.stale_frames
            while not self.enough(session):
                if interrupted():
                    outcome = "preempted"
                    return outcome
                pair = await _first(self.camera.read(), wake)
                if pair is None or pair.t < settled_at:
                    continue
                if stale > 0:                    # perhaps taken before the carriage stopped here
                    stale -= 1
                    continue
                if pair.t < session.last_pair_t + self.s.pair_interval_s:
                    continue
                self._measure(session, pair)
                self._refuse_unfit(session)
                while session.measuring and len(session.measuring) >= self.in_flight() and not interrupted():
                    await _first(asyncio.wait(set(session.measuring), timeout=self._left(session)), wake)
                    self._abandon_late(session)
                self._refuse_unfit(session)
            self.alarms.clear(f"device/{self.camera.name}", "survey camera back")
            outcome = "captured"
            return outcome
        except DeviceError as exc:
            session.failed = exc.text
            self.alarms.raise_(f"device/{self.camera.name}", f"survey of {session.tank} stopped: {exc.text}",
                               kind="unreachable")
            return outcome
        finally:
            self.release()                       # cancelled (an e-stop) too

    def _refuse_unfit(self, session: SurveySession) -> None:
        """A pair measured meanwhile whose frames the calibration cannot take: the camera's fault."""
        if session.unfit is not None:
            raise DeviceFault(self.camera.name, f"its frames do not fit: {session.unfit}")

    def release(self) -> None:
        """Stop the cameras' streams, in the background: nothing of the robot's waits for it. A start
        still waiting its turn is dropped instead: on a loaded machine at 600x, visits ended by demands
        once a wall second each queued a start and a stop behind cameras slow to open, and no survey
        was made in two farm days."""
        waiting = self._waiting
        if waiting is not None and waiting[0] == "start" and not waiting[1].done():
            waiting[1].cancel()                   # never began: the cameras stay as they were before it
            self._power, self._waiting = waiting[2], None
            return
        if self.camera.streaming or (self._power is not None and not self._power.done()):
            self._chain(self.camera.stop, "stop")

    def _chain(self, step, kind: str = "start") -> asyncio.Future:
        """``step()`` once the cameras' previous start or stop has ended: a stream is never opened
        while the last one is still closing. A visit waits for a start only as long as no demand
        comes; a stop, or a start that has begun, runs in turn though nobody waits for it any more."""
        before = self._power

        async def run():
            if before is not None:
                await asyncio.wait({before}, timeout=self.start_wall_s)
                if not before.done():
                    log.warning("%s: the cameras' last start or stop has not ended in %g s; going on",
                                self.camera.name, self.start_wall_s)
            if self._waiting is not None and self._waiting[1] is task:
                self._waiting = None              # begun: no longer droppable
            return await step()
        self._power = task = asyncio.ensure_future(run())
        self._waiting = (kind, task, before)
        task.add_done_callback(_retrieved)
        return task

    def _measure(self, session: SurveySession, pair) -> None:
        frame = session.captured
        session.captured += 1
        session.last_pair_t = pair.t
        job = PairJob(frame, f"{self.camera.name} pair {frame}", left=pair.left, right=pair.right)
        calib, setup = self.camera.calibration, self.setups[session.tank]
        loop = asyncio.get_running_loop()
        task = loop.run_in_executor(self.pool, lambda: list(self.measure(iter([job]), calib, setup)))
        session.measuring[task] = (frame, loop.time())
        task.add_done_callback(lambda t: self._measured(session, t))

    def _left(self, session: SurveySession) -> float:
        """Wall seconds until the oldest pair measuring is late (``measure_wall_s``)."""
        began = min(b for _, b in session.measuring.values())
        return max(0.0, began + self.measure_wall_s - asyncio.get_running_loop().time())

    def _abandon_late(self, session: SurveySession) -> None:
        """Pairs measuring for ``measure_wall_s`` are left out of the survey: their thread runs on,
        its result unused."""
        now = asyncio.get_running_loop().time()
        for task, (frame, began) in list(session.measuring.items()):
            if now - began >= self.measure_wall_s:
                del session.measuring[task]
                log.warning("survey of %s: pair %d not measured within %g s; left out", session.tank, frame,
                            self.measure_wall_s)

    def _measured(self, session: SurveySession, task: asyncio.Future) -> None:
        if session.measuring.pop(task, None) is None or task.cancelled():    # left out as late, or cancelled
            return
        if task.exception() is not None:
            log.warning("survey of %s: a pair not measured: %s", session.tank, task.exception())
            if isinstance(task.exception(), BadInput) and session.unfit is None:
                # frames of another size, grey where colour was calibrated...: every pair will be so.
                # Measured on, 40 pairs came to a survey of 0 fish whose alarm blamed the water
                session.unfit = str(task.exception())
            return
        session.measured += 1
        for result in task.result():
            for fish in result.fish:
                if math.isfinite(fish.length_cm) and fish.length_cm > 0:
                    session.lengths.append(float(fish.length_cm))
                    weight = float(self.species[session.tank].weight.weight_g(fish.length_cm))
                    session.entries.append(fish_entry(result.frame, len(session.entries), fish, weight))

    def finish(self, session: SurveySession) -> asyncio.Task:
        """Record the survey once its pairs are measured (in the background: the robot is free)."""
        task = asyncio.ensure_future(self._record(session))
        self.finishing.add(task)
        task.add_done_callback(self.finishing.discard)
        return task

    async def _record(self, session: SurveySession) -> int:
        while session.measuring:
            await asyncio.wait(set(session.measuring), timeout=self._left(session))
            self._abandon_late(session)
        # dated when the robot came to the tank, not when the last pair was measured: the schedule
        # counts a tank's next survey from the farm day of this one, and a survey begun at 23:55
        # and recorded at 00:14 had moved a daily survey to every other day (a weekly one to 8 days)
        t = session.began if session.began is not None else self.clock.now()
        measured = np.asarray(session.lengths, float)
        far = implausible(measured)
        lengths, rejected = measured[~far], [float(x) for x in measured[far]]
        for entry, out in zip(session.entries, far, strict=True):
            entry["outlier"] = bool(out)
        if rejected:
            log.warning("survey of %s: %d of %d lengths left out as measuring errors (%s cm)", session.tank,
                        len(rejected), len(session.lengths), ", ".join(f"{x:.1f}" for x in rejected))
        session.rejected = rejected
        sp = self.species[session.tank]
        weights = sp.weight.weight_g(lengths)
        path = self._write_out_json(session, t, lengths, weights)
        scores = [math.nan if e["score"] is None else e["score"] for e, out in zip(session.entries, far, strict=True)
                  if not out]
        sid = self.store.add_survey(session.tank, t, sp.key, path, lengths, weights, scores)
        self.recorded.append(sid)
        mean = f"mean {float(weights.mean()):.1f} g" if len(lengths) else "no mean weight"
        log.info("survey of %s recorded: %d pairs in %d visit(s), %d fish, %s", session.tank,
                 session.captured, session.visits, len(lengths), mean)
        return sid

    def _write_out_json(self, session: SurveySession, t: float, lengths, weights) -> str:
        # how many more fish the farm's own precision ([surveys] ci_pct) wanted, not the CLI's 2 %
        stats = summarise(lengths, weights, rng=np.random.default_rng(session.captured), target=self.s.ci_pct / 100)
        doc = {"species": self.species[session.tank].key, "setup": self.s.setup, "frames": session.captured,
               "fish": session.entries, "count": stats["count"], "length_cm": stats["length_cm"],
               "weight_g": stats["weight_g"], "precision": stats["precision"], "tank": session.tank,
               "requested_by": session.why, "visits": session.visits, "statistics_per": "fish",
               "rejected_lengths_cm": [round(x, 2) for x in session.rejected]}
        if session.cut_short is not None:
            doc["cut_short"] = session.cut_short
        out = Path(self.s.out_dir) / f"{session.tank}-{self.clock.iso(t).replace(':', '')}.json"
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            tmp = out.with_suffix(".tmp")
            tmp.write_text(json.dumps(doc))
            tmp.replace(out)
        except OSError as exc:          # the ledger keeps the survey all the same
            log.warning("survey of %s: OUT.json not written: %s", session.tank, exc)
            return f"survey stop {session.tank} ({session.why})"
        return str(out)

    async def close(self) -> None:
        for task in [*self.finishing]:
            task.cancel()
        self.pool.shutdown(wait=False, cancel_futures=True)
        with contextlib.suppress(Exception):
            await self.camera.stop()


def _retrieved(task: asyncio.Future) -> None:
    """A start or stop whose visit left: its fault is the next visit's to meet (logged here)."""
    if not task.cancelled() and task.exception() is not None:
        log.debug("survey cameras: %s", task.exception())


async def _until(clock, event: asyncio.Event, farm_s: float) -> None:
    """Until ``farm_s`` farm seconds have passed or ``event`` is set (cleared here)."""
    sleeper = asyncio.ensure_future(clock.asleep(farm_s))
    waiter = asyncio.ensure_future(event.wait())
    try:
        await asyncio.wait({sleeper, waiter}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        sleeper.cancel()
        waiter.cancel()
        event.clear()


async def _first(work, event: asyncio.Event):
    """``work``'s result, or None when ``event`` is set first (the work is then cancelled)."""
    task = asyncio.ensure_future(work)
    waiter = asyncio.ensure_future(event.wait())
    try:
        await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        waiter.cancel()
        if not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, DeviceError):
                await task
    event.clear()
    return task.result() if task.done() and not task.cancelled() else None
