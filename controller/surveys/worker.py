"""A vision worker: measures stereo pairs for any survey on the farm's Zenoh network
(``fishfarm worker``; the dispatcher is controller/surveys/remote.py, the format wire.py).

Keys (README, "Zenoh key space", additions):
- ``farm/{site}/worker/node/{id}``: the worker's liveliness token, present while it serves;
- ``farm/{site}/worker/node/{id}/pair``: its queryable, one job in, one reply out;
- ``farm/{site}/worker/calib/{sha256}``: declared by each dispatcher; a worker fetches a
  calibration there the first time a job names its hash, checks the content against the hash
  and keeps the last few.

Jobs are measured one at a time, in arrival order, on the main thread: Zenoh's callback only
queues the query (its threads must never block), and one pair per core is the parallelism, so
OpenCV runs single-threaded. Several surveys may share a worker; their jobs simply interleave.
"""
from __future__ import annotations

import json
import logging
import queue
import re
import threading
import time
from collections import OrderedDict

import zenoh

from controller.errors import BadInput
from controller.surveys import wire
from controller.surveys.frames import decode_pair
from controller.surveys.runner import MEASURE, check_frame_size, check_header_size, resolve
from vision.calib_file import CalibrationError, StereoCalibration, calibration_from_json

log = logging.getLogger("fishfarm.worker")

SITE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
CALIBRATIONS_KEPT = 8
FETCH_TIMEOUT_S = 5.0
ID_CHECK_S = 1.0         # a liveliness get's wait for an answer
ID_FREED_S = 3.0         # a killed predecessor's token goes when its link closes: well within this


def node_key(site: str, worker_id: str) -> str:
    return f"farm/{site}/worker/node/{worker_id}"


def calib_key(site: str, digest: str) -> str:
    return f"farm/{site}/worker/calib/{digest}"


class Refusal(Exception):
    """A job this worker will not or cannot measure: ``kind`` as in wire.py."""

    def __init__(self, kind: str, error: str):
        super().__init__(error)
        self.kind = kind


class Worker:
    """Serves ``node_key(site, id)/pair`` on ``session`` until ``stop`` is set."""

    def __init__(self, session: zenoh.Session, site: str, worker_id: str, measure: str = MEASURE):
        self.session, self.site, self.id = session, site, worker_id
        self.measure_name = measure
        self.measure = resolve(measure)
        self.calibrations: OrderedDict[str, StereoCalibration] = OrderedDict()
        self.inbox: queue.Queue = queue.Queue()
        self.served = 0
        self._declared: list = []

    def start(self) -> None:
        """Declares the queryable and the token; BadInput (``--id``) when another worker already
        serves under this name: a get reaches both, so every job was measured twice (an outside
        tester: 3x slower). A restarted worker's predecessor gets ID_FREED_S to vanish."""
        key = node_key(self.site, self.id)
        deadline = time.monotonic() + ID_FREED_S
        while self._name_taken(key):
            if time.monotonic() >= deadline:
                raise BadInput("--id", None, f"{self.id!r}: another worker serves as {key} (two of one name "
                                             "would both measure every job): stop it or give another --id")
            time.sleep(0.25)
        # the queryable first: a worker seen alive can always be asked
        self._declared.append(self.session.declare_queryable(
            f"{key}/pair", lambda q: self.inbox.put((q, time.perf_counter()))))
        self._declared.append(self.session.liveliness().declare_token(key))

    def _name_taken(self, key: str) -> bool:
        replies = self.session.liveliness().get(key, timeout=ID_CHECK_S)
        return any(r.ok is not None for r in replies)

    def serve(self, stop: threading.Event) -> None:
        while not stop.is_set():
            try:
                query, arrived = self.inbox.get(timeout=0.2)
            except queue.Empty:
                continue
            self.answer(query, arrived)

    def answer(self, query: zenoh.Query, arrived: float) -> None:
        job_id = None
        try:
            header, blobs = wire.decode_job(bytes(query.payload.to_bytes()) if query.payload else b"")
            job_id = header["job"]
            reply = self.measure_job(header, blobs, arrived)
        except wire.WireError as exc:
            reply = {"ok": False, "kind": "refused", "error": f"not a job: {exc}"}
        except Refusal as exc:
            reply = {"ok": False, "kind": exc.kind, "error": str(exc)}
        except BadInput as exc:
            reply = {"ok": False, "kind": "bad_input", "error": str(exc)}
        except Exception as exc:  # noqa: BLE001 - the dispatcher decides; this worker serves on
            log.exception("job %s failed", job_id)
            reply = {"ok": False, "kind": "internal", "error": f"{type(exc).__name__}: {exc}"}
        reply = {**reply, "job": job_id, "worker": self.id}
        try:
            query.reply(query.key_expr, wire.encode_reply(reply))
        except zenoh.ZError as exc:            # the survey gave up on it (timeout, ended)
            log.debug("reply to %s lost: %s", job_id, exc)
        finally:
            query.drop()
        self.served += 1

    def measure_job(self, header: dict, blobs: tuple[bytes, ...], arrived: float) -> dict:
        c0, t0 = time.process_time(), time.perf_counter()
        if header["measure"] != self.measure_name:
            raise Refusal("refused", f"this worker measures with {self.measure_name}, "
                                     f"the job asks for {header['measure']}")
        setup = wire.setup_from_json(header["setup"])
        calib = self.calibration(header["calib"])
        t1 = time.perf_counter()
        names = tuple(str(n) for n in header["names"])
        if len(names) != len(blobs):
            raise wire.WireError("names and images differ in number")
        check_header_size(calib, blobs, names)
        left, right, warning = decode_pair(blobs, names)
        check_frame_size(calib, left, names[0])
        t2 = time.perf_counter()
        timings = {"wait": t0 - arrived, "calib": t1 - t0, "decode": t2 - t1}
        fish = self.measure(left, right, calib, setup, timings)
        timings["measure"] = time.perf_counter() - t2
        timings["cpu"] = time.process_time() - c0
        return {"ok": True, "frame": header["frame"], "fish": [wire.fish_to_json(f) for f in fish],
                "timings": timings, "warning": warning}

    def calibration(self, digest: str) -> StereoCalibration:
        """The calibration ``digest`` names, fetched from the survey's queryable the first time."""
        if digest in self.calibrations:
            self.calibrations.move_to_end(digest)
            return self.calibrations[digest]
        if not all(c in "0123456789abcdef" for c in digest) or len(digest) != 64:
            raise Refusal("calibration", f"calibration {digest[:80]!r} is not a sha256 hex digest")
        data = None
        for reply in self.session.get(calib_key(self.site, digest), timeout=FETCH_TIMEOUT_S):
            if reply.ok is not None:
                got = bytes(reply.ok.payload.to_bytes())
                if wire.content_hash(got) == digest:     # any survey holding it may answer
                    data = got
                    break
        if data is None:
            raise Refusal("calibration", f"calibration {digest} unknown: nobody serves "
                                         f"{calib_key(self.site, digest)}")
        try:
            calib = calibration_from_json(json.loads(data))
        except (ValueError, CalibrationError) as exc:
            raise Refusal("calibration", f"calibration {digest}: {exc}") from None
        self.calibrations[digest] = calib
        while len(self.calibrations) > CALIBRATIONS_KEPT:
            self.calibrations.popitem(last=False)
        return calib

    def close(self) -> None:
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except zenoh.ZError:
                pass
        self._declared.clear()
