"""Measure a source's pairs on every core, results back in frame order.

Each worker process runs OpenCV on one thread (``cv2.setNumThreads(1)``): with one pair per core
the pairs are the parallelism, and OpenCV's own threads would only fight over the same cores.
At most ``2 x workers`` pairs are in flight, so memory stays flat whatever the length of the
footage; results are yielded strictly in frame order (the tracker needs them in order).

A survey that ends early (a signal, a bad frame, its consumer gone) terminates its workers rather
than waiting for the pairs they hold; a survey process killed outright (SIGKILL: no chance to)
is outlived by none: each worker watches it and exits once it is gone (a worker's parent is the
forkserver, so the kernel's parent-death signal cannot say it), and the shared frames are a file
without a name, gone with the last process that maps it.

``measure`` is the per-pair function, ``vision.survey.measure_pair`` unless a test or a caller
hands another with the same signature (a "module:function" string or a top-level function: it
travels to the workers by name). It must not write into its frames: decoded frames reach the
workers read-only (a shared slot carries a later pair next).
"""
from __future__ import annotations

import contextlib
import importlib
import math
import multiprocessing
import os
import select
import signal
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import resource_tracker

import cv2
import numpy as np

from controller.errors import BadInput
from controller.surveys.frame_pixels import header_size
from controller.surveys.frames import PairJob, check_same_dims, read_pair
from devices.elastic_clock import process_alive
from vision.calib_file import CalibrationError, StereoCalibration, check_image_size
from vision.survey_types import FishMeasurement, SurveySetup

MEASURE = "vision.survey:measure_pair"
Measure = Callable[..., list[FishMeasurement]]


@dataclass
class PairResult:
    frame: int
    where: str
    fish: list[FishMeasurement]
    timings: dict[str, float] = field(default_factory=dict)   # seconds per stage, "read" included
    warning: str | None = None
    worker: str | None = None        # the vision worker that measured it (remote.py); None: here


def resolve(measure: str | Measure) -> Measure:
    if callable(measure):
        return measure
    module, _, attr = measure.partition(":")
    return getattr(importlib.import_module(module), attr)


def check_frame_size(calib: StereoCalibration, image, where: str) -> None:
    """A calibration made for one image size does not fit frames of another (its pixels would be
    measured with the wrong camera matrices). The one place the survey checks it."""
    h, w = image.shape[:2]
    try:
        check_image_size(calib, (w, h))
    except CalibrationError as exc:
        raise BadInput(where, None, f"does not fit the calibration: {exc}") from None


# a still's pixels beyond which it is refused from its header, whatever the calibration says (one
# without image_size let a 0.9 MB PNG of 30000x30000 be decoded: 5.1 GB; a worker took 1.37 GB for
# a 20000x20000 job): an 8K camera has 33 megapixels
MAX_STILL_PX = 50_000_000


def check_header_size(calib: StereoCalibration, sources, names) -> None:
    """``check_frame_size`` from the files' headers (paths or bytes), before they are decoded: a
    frame of the wrong size is refused without decoding it. Only a size that fits neither way round
    is refused here (an EXIF orientation may turn the decoded frame); the decoded frame is checked
    again anyway. Two views of different sizes are told as such first, as ``read_pair`` tells them."""
    sizes = [header_size(source) for source in sources]
    for size, name in zip(sizes, names, strict=True):
        if size is not None and size[0] * size[1] > MAX_STILL_PX:
            raise BadInput(name, None, f"{size[0]}x{size[1]} pixels: more than any survey camera's "
                                       f"{MAX_STILL_PX // 1_000_000} megapixels (decoded, it would take "
                                       f"{size[0] * size[1] * 3 / 2**30:.1f} GB)")
    if len(sizes) == 2 and None not in sizes and sizes[0] != sizes[1][::-1]:     # a turned one may be EXIF's
        check_same_dims(*sizes, *names)
    for size, name in zip(sizes, names, strict=True):
        if size is None:
            continue
        try:
            check_image_size(calib, size)
        except CalibrationError as exc:
            try:
                check_image_size(calib, size[::-1])
            except CalibrationError:
                raise BadInput(name, None, f"does not fit the calibration: {exc}") from None


class PairWork:
    """What a worker does with one job: read it (if it names files), check it, measure it."""

    def __init__(self, calib: StereoCalibration, setup: SurveySetup, measure: str | Measure):
        self.calib, self.setup, self.measure = calib, setup, resolve(measure)

    def __call__(self, job: PairJob) -> PairResult:
        c0 = time.process_time()
        t0 = time.perf_counter()
        if job.paths:
            check_header_size(self.calib, job.paths, job.paths)
        left, right, warning = read_pair(job)
        timings = {"read": job.read_s + time.perf_counter() - t0}
        check_frame_size(self.calib, left, job.paths[0] if job.paths else job.where)
        t1 = time.perf_counter()
        fish = self.measure(left, right, self.calib, self.setup, timings)
        timings["measure"] = time.perf_counter() - t1
        timings["cpu"] = time.process_time() - c0        # this worker's CPU for the pair: robust to load
        return PairResult(job.frame, job.where, fish, timings, warning)


class FrameRing:
    """Decoded frames handed to the workers through a file in /dev/shm (shared memory) instead of
    the pool's pipe: pickling a 1280x960 colour pair through a pipe costs ~10 ms of CPU, a copy
    into the map ~1 ms. Slot k % slots holds job k; with at most ``slots`` jobs in flight and
    results taken in order, a slot is free again when its next job comes."""

    def __init__(self, slots: int):
        self.slots = slots
        self.k = 0
        self.file = None
        self.map = None

    def _open(self, slot_bytes: int) -> None:
        where = "/dev/shm" if os.path.isdir("/dev/shm") else None
        # a file with no name, reached through this process's descriptor: nothing is left behind
        # in /dev/shm whenever this process dies (SIGKILL included); a named one where no /proc
        self.file = tempfile.TemporaryFile(prefix="fishfarm-survey-", dir=where)
        self.path = f"/proc/{os.getpid()}/fd/{self.file.fileno()}"
        if not os.path.exists(self.path):
            self.file.close()
            self.file = tempfile.NamedTemporaryFile(prefix="fishfarm-survey-", dir=where)
            self.path = self.file.name
        self.file.truncate(self.slots * slot_bytes)
        self.map = np.memmap(self.file, np.uint8, "r+", shape=(self.slots, slot_bytes))

    def put(self, job: PairJob) -> PairJob:
        left, right = np.ascontiguousarray(job.left), np.ascontiguousarray(job.right)
        size = left.nbytes + right.nbytes
        if self.map is None:
            self._open(size)
        if size > self.map.shape[1] or left.dtype != np.uint8 or right.dtype != np.uint8:
            return job                                       # a frame that does not fit: by pipe
        slot = self.k % self.slots
        self.k += 1
        row = self.map[slot]
        row[:left.nbytes] = left.reshape(-1)
        row[left.nbytes:size] = right.reshape(-1)
        return PairJob(job.frame, job.where, job.paths, read_s=job.read_s,
                       shared=(self.path, slot * self.map.shape[1], left.shape, right.shape), warning=job.warning)

    def close(self) -> None:
        if self.file is not None:
            self.map = None
            self.file.close()


_work: PairWork | None = None
_maps: dict[str, np.memmap] = {}


def _init_worker(calib, setup, measure, survey_pid: int | None = None) -> None:
    global _work
    cv2.setNumThreads(1)
    _work = PairWork(calib, setup, measure)
    if survey_pid is not None:
        threading.Thread(target=_outlive_no_survey, args=(survey_pid,), name="survey-watch", daemon=True).start()


def _outlive_no_survey(pid: int) -> None:
    """Return never; end this worker once process ``pid`` is gone."""
    try:
        fd = os.pidfd_open(pid)            # readable when the process ends; no pid reuse to fear
    except ProcessLookupError:
        fd = -1
    except (AttributeError, OSError):      # no pidfd (not Linux 5.3+): ask every second
        fd = None
    if fd is None:
        while process_alive(pid):
            time.sleep(1.0)
    elif fd >= 0:
        select.select([fd], [], [])
    os._exit(0)


def _start_resource_tracker() -> None:
    """multiprocessing's resource tracker (the pool's semaphores are registered with it), started
    with SIGHUP blocked, which it keeps through exec: it ignores SIGINT and SIGTERM but not SIGHUP,
    so a hangup of the survey's process group (its terminal closed) killed it, and the survey's
    clean-up printed a warning and a traceback a semaphore (KeyError in resource_tracker.py) as it
    relaunched one that knew none of them. Blocked, not ignored: a hangup meanwhile waits for this
    thread to unblock it, or is taken by another. The tracker ends with the last process holding
    its pipe, as before."""
    before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGHUP})
    try:
        resource_tracker.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


MANAGER_JOIN_S = 3.0        # wall: the most an abandoned pool's manager thread is waited for


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Terminate a pool's workers now, whatever they hold (3.14 says it: terminate_workers)."""
    if hasattr(pool, "terminate_workers"):
        pool.terminate_workers()
        return
    for proc in list((getattr(pool, "_processes", None) or {}).values()):
        with contextlib.suppress(Exception):
            proc.terminate()


def _run(job: PairJob) -> PairResult:
    if job.shared is not None:
        path, offset, lshape, rshape = job.shared
        if path not in _maps:
            _maps.clear()
            # read-only: a detector writing into its frames is refused. Copy-on-write would let it,
            # and the pages it wrote stay private to this worker's map, so later pairs in the slot
            # would be measured on its writing instead of their own frames
            _maps[path] = np.memmap(path, np.uint8, "r")
        m = _maps[path]
        nl, nr = math.prod(lshape), math.prod(rshape)
        job.left = m[offset:offset + nl].reshape(lshape)
        job.right = m[offset + nl:offset + nl + nr].reshape(rshape)
    return _work(job)


def _read_in_parent(job: PairJob) -> PairJob:
    t0 = time.perf_counter()
    left, right, _ = read_pair(job)
    job.left, job.right = left, right
    job.read_s = time.perf_counter() - t0
    return job


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:          # not Linux
        return max(1, os.cpu_count() or 1)


def measure_all(jobs: Iterable[PairJob], calib: StereoCalibration, setup: SurveySetup, *,
                measure: str | Measure = MEASURE, workers: int | None = None,
                read_in: str = "worker") -> Iterator[PairResult]:
    """Every job measured, in order. ``workers`` 1 runs in this process (no pool);
    ``read_in="parent"`` decodes image files here and ships the arrays (the benchmark compares)."""
    workers = workers or default_workers()
    if read_in == "parent":
        jobs = (_read_in_parent(j) if j.left is None else j for j in jobs)
    if workers == 1:
        work = PairWork(calib, setup, measure)
        yield from (work(job) for job in jobs)
        return
    # forkserver: workers start from a clean interpreter, not a fork of one holding threads
    # (the progress bar's) and OpenCV's thread pool
    ctx = multiprocessing.get_context("forkserver")
    # (before the forkserver starts: a worker started as a signalled survey exits dies quietly)
    ctx.set_forkserver_preload(["controller.surveys.worker_start"])
    # one BLAS thread per worker too: with a pair per core, threaded matrix products only contend
    # (measured ~10x slower under load); the forkserver starts with this environment
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    _start_resource_tracker()
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker,
                               initargs=(calib, setup, measure, os.getpid()))
    pending: deque = deque()
    ring = FrameRing(2 * workers)
    finished = False
    try:
        for job in jobs:
            pending.append(pool.submit(_run, ring.put(job) if job.left is not None else job))
            if len(pending) >= 2 * workers:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
        finished = True
    finally:
        for f in pending:
            f.cancel()
        manager = None
        if not finished:            # abandoned: the pairs in flight are not waited for
            _stop_workers(pool)
            manager = getattr(pool, "_executor_manager_thread", None)
        pool.shutdown(wait=finished, cancel_futures=True)
        if manager is not None:
            # its workers gone, the pool's manager thread ends at once; joined (bounded) so that it
            # has closed its wake-up pipe before the interpreter's exit writes to it: the two raced
            # (CPython 3.12), and a Ctrl-C'd survey printed "Exception ignored ... Bad file descriptor"
            manager.join(timeout=MANAGER_JOIN_S)
        ring.close()
