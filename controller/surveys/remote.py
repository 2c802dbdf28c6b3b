"""A survey's pairs measured by vision workers over Zenoh, results back in frame order.

The entry point, for ``fishfarm survey --workers ENDPOINT`` and for the controller::

    from controller.surveys.remote import measure_remote
    for result in measure_remote(jobs, calib, setup, session=bus.session, site=bus.site):
        ...                                    # PairResult, in frame order, each frame once

It has the shape of ``runner.measure_all`` (PairJob in, PairResult out, frame order, bounded
in flight) and blocks its caller: the controller runs it off its event loop (a thread, e.g.
``asyncio.to_thread`` over a list or a loop feeding a queue). ``session`` is any open Zenoh
session that reaches the workers (the controller's own, or one from ``connect``).

How it goes:
- workers are known by their liveliness tokens (``farm/{site}/worker/node/{id}``, see
  worker.py); none within ``discover_s``: the whole survey is measured here by ``measure_all``
  (local processes);
- jobs go to the live worker with the fewest outstanding, at most ``per_worker`` each (one
  measured, one waiting, so a worker never idles for a round trip), and at most
  ``per_worker x workers`` frames are between reading and yielding (memory stays flat);
- the calibration travels by reference: its sha256 names a queryable this survey declares
  (``farm/{site}/worker/calib/{sha256}``); a worker fetches it once and keeps it;
- a job is re-run elsewhere when its worker's token goes (the process died or its link broke),
  when no reply comes within ``timeout_s``, or when the reply is garbage or a refusal: that
  worker gets no more jobs from this survey. When no usable worker is left, the rest is measured
  here, one pair at a time. Each frame's first result is kept, later ones dropped: every frame
  is in the results exactly once;
- a pair the worker finds at fault (unreadable image, wrong size for the calibration) stops the
  survey with the same BadInput a local run raises.
"""
from __future__ import annotations

import itertools
import json
import logging
import math
import queue
import time
import uuid
from collections import defaultdict, deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import zenoh

from controller.errors import BadInput
from controller.surveys import wire
from controller.surveys.frames import PairJob
from controller.surveys.runner import MEASURE, PairResult, PairWork, measure_all
from controller.surveys.worker import calib_key, node_key
from controller.zenoh_config import _one_line, client_config
from vision.calib_file import StereoCalibration
from vision.survey_types import SurveySetup

log = logging.getLogger("fishfarm.survey")

DISCOVER_S = 1.0
TIMEOUT_S = 30.0           # a pair takes well under a second; this is for a hung worker
PER_WORKER = 2
HISTORY_QUIET_S = 0.01     # wall: the liveliness history is in once no token came for this long
BENCH_S = 120.0            # wall: a worker dropped by one dispatch gets no job from the later dispatches
                           # that share its ``benched`` for this long (the survey stop makes one a pair:
                           # a SIGSTOPped worker held every other pair for ``timeout_s`` and was logged each time)
# The survey stop sends each pair in a call of its own, so a dispatch's own load count starts at
# zero every time: ties are broken by a turn that moves on with each dispatch of this process,
# or every pair would go to the same worker (measured: one of two workers did 1 % of a grow-out's).
_TURNS = itertools.count()
_said_here = [-math.inf]     # monotonic: when "measuring the rest here" was last said at warning


def _say_measuring_here() -> None:
    """Once a ``BENCH_S``, at warning: the survey stop dispatches each pair on its own, and said it
    of every pair of a visit (3-4 lines in half a second); in between, at debug."""
    now = time.monotonic()
    loud = now - _said_here[0] >= BENCH_S
    if loud:
        _said_here[0] = now
    log.log(logging.WARNING if loud else logging.DEBUG, "no usable vision worker left: measuring the rest here")


def measure_remote(jobs: Iterable[PairJob], calib: StereoCalibration, setup: SurveySetup, *,
                   session: zenoh.Session, site: str = "demo", measure: str = MEASURE,
                   discover_s: float = DISCOVER_S, timeout_s: float = TIMEOUT_S, per_worker: int = PER_WORKER,
                   local_workers: int | None = None, announce: bool = True,
                   known: Callable[[], set[str]] | None = None,
                   benched: dict[str, float] | None = None) -> Iterator[PairResult]:
    """Every job measured, in order, by the workers on ``session``'s network (or here, if none;
    said at info level unless ``announce`` is False: the survey stop asks once a pair).
    ``known``: the workers a long-lived liveliness subscriber has heard alive (the survey stop's):
    with some, the dispatch starts at once, every one of them in its turns, instead of waiting for
    a quiet spell in its own subscriber's history (in which, on a loaded machine, the second
    worker's token can come after the spell: every pair of the survey to the first).
    ``benched``: worker -> ``time.monotonic()`` until which it gets no job, shared by the calls of
    one caller: a worker this dispatch drops is put there for ``BENCH_S`` (and said once for it)."""
    if not isinstance(measure, str):
        raise TypeError("measure travels by name to the workers: give 'module:function'")
    dispatch = _Dispatch(session, site, calib, setup, measure, timeout_s, per_worker,
                         {} if benched is None else benched)
    try:
        if not dispatch.discover(discover_s, known() if known is not None else ()):
            (log.info if announce else log.debug)("no vision worker on farm/%s: measuring here", site)
            yield from measure_all(jobs, calib, setup, measure=measure, workers=local_workers)
            return
        yield from dispatch.run(jobs)
    finally:
        dispatch.close()


def connect(endpoint: str, *, timeout_s: float = 2.0, user: str | None = None,
            password: str | None = None) -> tuple[zenoh.Session, bool]:
    """A session for a survey run from the command line: a client of whatever listens at
    ``endpoint`` (the controller, a router), or, when nothing does, a peer listening there itself,
    so workers started with ``--connect endpoint`` join it. (session, listening). With a ``user``
    the endpoint is a deployment's router (config/zenoh/deploy.json5): it is that or nothing."""
    zc = client_config(endpoint, user, password, timeout_s=timeout_s, option="--workers")
    try:
        return zenoh.open(zc), False
    except zenoh.ZError as exc:
        if user is not None or password is not None:
            raise BadInput("--workers", None, f"cannot log in at {endpoint} as {user!r}: "
                                              f"{_one_line(exc)}") from None
    hub = client_config(endpoint, mode="peer", timeout_s=timeout_s, option="--workers")
    hub.insert_json5("connect/endpoints", "[]")
    hub.insert_json5("listen/endpoints", json.dumps([endpoint]))
    try:
        return zenoh.open(hub), True
    except zenoh.ZError as exc:
        raise BadInput("--workers", None, f"cannot reach or listen on {endpoint}: {_one_line(exc)}") from None


@dataclass(eq=False)
class _Job:
    seq: int
    job: PairJob
    id: str
    payload: bytes
    encode_s: float
    asked: set[str] = field(default_factory=set)     # workers whose answer is awaited
    queued: bool = False
    finished: bool = False                           # its result is in (done, or yielded already)


class _Dispatch:
    def __init__(self, session: zenoh.Session, site: str, calib: StereoCalibration, setup: SurveySetup,
                 measure: str, timeout_s: float, per_worker: int, benched: dict[str, float]):
        self.benched = benched
        self.session, self.site, self.calib, self.setup, self.measure = session, site, calib, setup, measure
        self.timeout_s, self.per_worker = timeout_s, max(1, per_worker)
        self.events: queue.Queue = queue.Queue()
        self.live: set[str] = set()
        self.excluded: dict[str, str] = {}
        self.busy: dict[str, int] = defaultdict(int)
        self.asked: dict[str, dict[str, _Job]] = defaultdict(dict)
        self.local: PairWork | None = None
        self.order: deque[int] = deque()             # jobs read, not yet yielded, in frame order
        self.done: dict[int, PairResult] = {}         # results waiting for their turn
        self.resend: deque[_Job] = deque()            # jobs waiting for a worker
        self.survey = uuid.uuid4().hex[:12]
        self.turn = next(_TURNS)
        data = wire.calibration_bytes(calib)
        self.digest = wire.content_hash(data)
        self.header = {"calib": self.digest, "setup": wire.setup_to_json(setup), "measure": measure}
        geo = setup.geometry
        self.lengths_cm = (geo.min_length_cm, geo.max_length_cm)
        self.pool = ThreadPoolExecutor(max_workers=64, thread_name_prefix="survey-ask")
        self.prefix = node_key(site, "")
        self._declared = [
            session.declare_queryable(calib_key(site, self.digest), lambda q: _answer_calib(q, data)),
            session.liveliness().declare_subscriber(f"{self.prefix}*", self._on_token, history=True),
        ]

    # ---- workers -------------------------------------------------------------------------

    def _on_token(self, sample: zenoh.Sample) -> None:
        worker = str(sample.key_expr)[len(self.prefix):]
        self.events.put(("alive" if sample.kind == zenoh.SampleKind.PUT else "gone", worker))

    def usable(self) -> list[str]:
        now = time.monotonic()
        return [w for w in self.live if w not in self.excluded and self.benched.get(w, 0.0) <= now]

    def discover(self, within_s: float, known=()) -> bool:
        self.live.update(known)
        if self.usable():
            return True
        deadline = time.monotonic() + within_s
        while not self.usable():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            try:
                self._handle(self.events.get(timeout=left))
            except queue.Empty:
                return False
        # the other workers' tokens of the liveliness history come in one by one: taken as they
        # are until a quiet spell, or the first worker heard would get every job of a dispatch
        # (the survey stop makes one a pair, so its turns would not share the pairs out)
        quiet_until = min(deadline, time.monotonic() + HISTORY_QUIET_S)
        while (left := quiet_until - time.monotonic()) > 0:
            try:
                self._handle(self.events.get(timeout=left))
            except queue.Empty:
                break
            quiet_until = min(deadline, time.monotonic() + HISTORY_QUIET_S)
        return bool(self.usable())

    def _exclude(self, worker: str, why: str) -> None:
        if worker in self.excluded:
            return
        self.excluded[worker] = why
        now = time.monotonic()
        if self.benched.get(worker, 0.0) <= now:       # not said already by an earlier dispatch
            log.warning("vision worker %s: %s; its jobs go elsewhere for %g s", worker, why, BENCH_S)
        self.benched[worker] = now + BENCH_S

    # ---- the run -------------------------------------------------------------------------

    def run(self, jobs: Iterable[PairJob]) -> Iterator[PairResult]:
        it = iter(jobs)
        exhausted = False
        seq = 0
        while True:
            self._drain()
            while not exhausted and len(self.order) < self.per_worker * max(1, len(self.usable())):
                try:
                    job = next(it)
                except StopIteration:
                    exhausted = True
                    break
                self._queue(self._prepare(seq, job))
                self.order.append(seq)
                seq += 1
            self._send()
            if self.resend and not self.usable():
                self._measure_here(self.resend.popleft())
            while self.order and self.order[0] in self.done:
                yield self.done.pop(self.order.popleft())
            if exhausted and not self.order:
                return
            if not (self.resend and not self.usable()):
                self._wait(0.5)

    def _prepare(self, seq: int, job: PairJob) -> _Job:
        t0 = time.perf_counter()
        blobs, names = wire.job_blobs(job)
        job_id = f"{self.survey}-{seq}"
        payload = wire.encode_job({"job": job_id, "frame": job.frame, "where": job.where, "names": list(names),
                                   **self.header}, blobs)
        return _Job(seq, job, job_id, payload, time.perf_counter() - t0 + job.read_s)

    def _queue(self, rec: _Job, first: bool = False) -> None:
        if rec.finished or rec.queued:
            return
        rec.queued = True
        (self.resend.appendleft if first else self.resend.append)(rec)

    def _send(self) -> None:
        while self.resend:
            rec = self.resend[0]
            if rec.finished:
                self.resend.popleft()
                rec.queued = False
                continue
            free = [w for w in self.usable() if self.busy[w] < self.per_worker and w not in rec.asked]
            if not free:
                return
            worker = self._least_busy(free)
            self.resend.popleft()
            rec.queued = False
            rec.asked.add(worker)
            self.busy[worker] += 1
            self.asked[worker][rec.id] = rec
            self.pool.submit(self._ask, rec, worker)

    def _least_busy(self, free: list[str]) -> str:
        """The free worker with the fewest jobs; among equals, the next in turn."""
        ring = sorted(self.usable())
        turn = {w: (ring.index(w) - self.turn) % len(ring) for w in free}
        return min(free, key=lambda w: (self.busy[w], turn[w]))

    def _ask(self, rec: _Job, worker: str) -> None:
        """On a pool thread: one get, its outcome to the event queue."""
        t0 = time.perf_counter()
        outcome: dict | str
        try:
            replies = list(self.session.get(f"{node_key(self.site, worker)}/pair", payload=rec.payload,
                                            timeout=self.timeout_s))
            good = [r.ok for r in replies if r.ok is not None]
            if not good and not replies and time.perf_counter() - t0 < 0.9 * self.timeout_s:
                outcome = "gone (no reply, and nobody answering there any more)"      # killed, not slow
            elif not good:
                outcome = f"no reply within {self.timeout_s:g} s" if not replies else "error reply"
            else:
                outcome = wire.decode_reply(bytes(good[0].payload.to_bytes()), rec.id, self.lengths_cm)
        except wire.WireError as exc:
            outcome = f"garbage reply ({exc})"
        except Exception as exc:  # noqa: BLE001 - whatever it is, the job goes elsewhere
            outcome = f"{type(exc).__name__}: {exc}"
        self.events.put(("answer", rec, worker, outcome, time.perf_counter() - t0))

    def _measure_here(self, rec: _Job) -> None:
        rec.queued = False
        if rec.finished:
            return
        if self.local is None:
            _say_measuring_here()
            self.local = PairWork(self.calib, self.setup, self.measure)
        self.done[rec.seq] = self.local(rec.job)
        rec.finished = True

    # ---- events --------------------------------------------------------------------------

    def _wait(self, timeout_s: float) -> None:
        try:
            self._handle(self.events.get(timeout=timeout_s))
        except queue.Empty:
            pass

    def _drain(self) -> None:
        while True:
            try:
                self._handle(self.events.get_nowait())
            except queue.Empty:
                return

    def _handle(self, event: tuple) -> None:
        kind, *rest = event
        if kind == "alive":
            if rest[0] not in self.live:
                # its token came (again) while this dispatch ran: a worker restarted under its --id
                # is used at once (benched by its name, the one that died, it was left out 120 s);
                # a token the liveliness history replays for a worker known live changes nothing
                self.excluded.pop(rest[0], None)
                self.benched.pop(rest[0], None)
            self.live.add(rest[0])
        elif kind == "gone":
            worker = rest[0]
            self.live.discard(worker)
            for rec in list(self.asked[worker].values()):
                self._queue(rec, first=True)           # its answer may never come
        else:
            self._answered(*rest)

    def _answered(self, rec: _Job, worker: str, outcome: dict | str, rtt: float) -> None:
        self.busy[worker] -= 1
        self.asked[worker].pop(rec.id, None)
        rec.asked.discard(worker)
        if isinstance(outcome, dict) and outcome["ok"]:
            if not rec.finished:           # a re-run's twin may have answered first
                self.done[rec.seq] = self._result(rec, worker, outcome, rtt)
                rec.finished = True
            return
        if isinstance(outcome, dict) and outcome.get("kind") == "bad_input":
            raise BadInput(outcome["error"])
        why = outcome if isinstance(outcome, str) else f"{outcome.get('kind')}: {outcome['error']}"
        self._exclude(worker, why)
        if not rec.asked:
            self._queue(rec, first=True)

    def _result(self, rec: _Job, worker: str, reply: dict, rtt: float) -> PairResult:
        timings = {k: float(v) for k, v in reply.get("timings", {}).items() if isinstance(v, (int, float))}
        served = sum(timings.get(k, 0.0) for k in ("wait", "calib", "decode", "measure"))
        timings["encode"] = rec.encode_s
        timings["transport"] = max(0.0, rtt - served)
        warning = reply.get("warning") if isinstance(reply.get("warning"), str) else rec.job.warning
        return PairResult(rec.job.frame, rec.job.where, reply["fish"], timings, warning, worker=worker)

    def close(self) -> None:
        for entity in self._declared:
            try:
                entity.undeclare()
            except zenoh.ZError:
                pass
        self.pool.shutdown(wait=False, cancel_futures=True)


def _answer_calib(query: zenoh.Query, data: bytes) -> None:
    try:
        query.reply(query.key_expr, data, encoding=zenoh.Encoding.APPLICATION_JSON)
    except zenoh.ZError:
        pass
    finally:
        query.drop()
