"""The tower camera through OpenCV's VideoCapture: RTSP/HTTP URLs, video files, device indices.

One reader thread per camera pulls frames as fast as the source gives them (so FFmpeg's own
buffers never fill with old frames) and keeps only the newest, stamped with farm time at
arrival. ``read()`` on the loop waits for a frame newer than the last it returned. The source
failing to open, or a read failing (the server gone, the connection reset, no data for
``read_timeout_s``), is a lost link: ``read()`` raises LinkDown while the thread reconnects with
back-off (``reconnect_s``); the loss and the recovery are logged once each.

A video file is played at its own frame rate in farm time (``CAP_PROP_FPS``, 25 when it does not
say): decoded as fast as it goes, a 30 s clip passed in under a second and the float moved thirty
times too fast. A file that ends is gone for good (LinkDown from then on, logged once): reopened,
it replayed old footage to the steering and flapped lost/back every second; with ``loop_file``
it starts over instead.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import threading
import time
from typing import Any

import cv2
from pydantic import Field, field_validator

from devices.base import Section
from devices.camera import Frame, TowerCamera
from devices.errors import DeviceTimeout, LinkDown

log = logging.getLogger(__name__)

FILE_FPS = 25.0          # a video file's frame rate when it does not give one
APIS = {"any": cv2.CAP_ANY, "ffmpeg": cv2.CAP_FFMPEG, "gstreamer": cv2.CAP_GSTREAMER, "v4l2": cv2.CAP_V4L2}



def known_api(api: str) -> str:
    """A VideoCapture backend name this driver knows (a config validator's check)."""
    if api not in APIS:
        raise ValueError(f"api must be one of {', '.join(APIS)}")
    return api


class SourceLink(Section):
    """How a VideoCapture source is reached: what the tower camera and the survey cameras share."""

    api: str = Field("any", description="VideoCapture backend: " + ", ".join(APIS))
    open_timeout_s: float = Field(5.0, gt=0, le=60, description="wall seconds to open the source")
    reconnect_s: tuple[float, ...] = Field((0.2, 0.5, 1.0, 2.0, 5.0), min_length=1,
                                           description="wall back-off between reconnects; the last repeats")
    ffmpeg_options: str | None = Field(None, description='FFmpeg options for this source, OpenCV\'s '
                                       '"key;value|key;value" (e.g. "rtsp_transport;tcp", "recv_buffer_size;262144")')

    @field_validator("api")
    @classmethod
    def _api(cls, api: str) -> str:
        return known_api(api)

    @field_validator("reconnect_s")
    @classmethod
    def _backoff(cls, steps):
        if any(not 0 < s <= 600 for s in steps):
            raise ValueError("every reconnect_s step must lie in (0, 600]")
        return steps


class Config(SourceLink):
    source: str | int = Field(description="an RTSP/HTTP URL, a video file, or a device index (0, 1, ...)")

    @field_validator("source")
    @classmethod
    def _some_source(cls, source: str | int) -> str | int:
        if isinstance(source, str) and not source.strip():
            raise ValueError("empty: an RTSP/HTTP URL, a video file or a device index")
        if isinstance(source, int) and source < 0:
            raise ValueError(f"device index {source}: 0 or more")
        return source
    read_timeout_s: float = Field(2.0, gt=0, le=60, description="wall seconds without a frame = gone")
    loop_file: bool = False


_ENV = "OPENCV_FFMPEG_CAPTURE_OPTIONS"
_env_lock = threading.Lock()


@contextlib.contextmanager
def _ffmpeg_options(options: str | None):
    """OpenCV reads FFmpeg's options from the environment when a capture opens: set them for
    this open only (one open at a time), and put back what was there."""
    if options is None:
        yield
        return
    with _env_lock:
        before = os.environ.get(_ENV)
        os.environ[_ENV] = options
        try:
            yield
        finally:
            if before is None:
                os.environ.pop(_ENV, None)
            else:
                os.environ[_ENV] = before


def _source(source: str | int) -> str | int:
    return int(source) if isinstance(source, str) and source.isdigit() else source


class CaptureCamera(TowerCamera):
    Config = Config

    def __init__(self, name: str, config: Config, clock: Any):
        super().__init__(name, config, clock)
        self.skipped = 0
        self.received = 0
        self.start_frame = 0      # a video file: the frame to play from (``position`` of the last camera on it)
        self.reconnects = 0
        self._cond = threading.Condition()        # guards the fields below
        self._newest: Frame | None = None
        self._down: str | None = None             # why the source is gone, None while it streams
        self._returned = 0                         # seq of the last frame read() returned
        self._stop = threading.Event()
        self._ended = False                        # a video file played to its end: gone for good
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._news: asyncio.Event | None = None

    async def _open(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._news = asyncio.Event()
        cap = await in_daemon_thread(self._connect, f"{self.name}-open")
        if cap is None:
            raise LinkDown(self.name, f"cannot open {self.config.source!r}")
        self._thread = threading.Thread(target=self._run, args=(cap,), name=f"{self.name}-reader", daemon=True)
        self._thread.start()

    @property
    def position(self) -> int:
        """A video file's next frame: where a camera opened on it later goes on from."""
        return self.start_frame + self.received

    async def _close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            # the thread may be inside an open or a read, each bounded by its timeout. Polled, not
            # joined from asyncio's executor: the interpreter waits for that executor's threads at
            # exit, and a stalled stream (read_timeout_s up to 60) made a clean stop overrun its
            # watchdog (exit 70). The reader is a daemon: a process ending leaves it behind.
            cfg = self.config
            until = time.monotonic() + max(cfg.read_timeout_s, cfg.open_timeout_s) + 2.0
            while self._thread.is_alive() and time.monotonic() < until:
                await asyncio.sleep(0.02)
            self._thread = None

    # --- the reader thread ----------------------------------------------------------------------
    def _connect(self) -> cv2.VideoCapture | None:
        cfg = self.config
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, round(cfg.open_timeout_s * 1000),
                  cv2.CAP_PROP_READ_TIMEOUT_MSEC, round(cfg.read_timeout_s * 1000)]
        try:
            with _ffmpeg_options(cfg.ffmpeg_options):
                cap = cv2.VideoCapture(_source(cfg.source), APIS[cfg.api], params)
        except cv2.error as exc:
            log.debug("%s: VideoCapture(%r): %s", self.name, cfg.source, exc)
            return None
        if not cap.isOpened():
            cap.release()
            return None
        return cap

    def _run(self, cap: cv2.VideoCapture | None) -> None:
        attempt = 0
        while not self._stop.is_set():
            if cap is None:
                cap = self._connect()
                if cap is None:
                    self._mark_down(f"cannot open {self.config.source!r}")
                    steps = self.config.reconnect_s
                    self._stop.wait(steps[min(attempt, len(steps) - 1)])
                    attempt += 1
                    continue
                self.reconnects += 1
            attempt = 0
            why = self._stream(cap)
            cap.release()
            cap = None
            if why is not None:
                self._mark_down(why)
            if self._ended:
                return

    def _stream(self, cap: cv2.VideoCapture) -> str | None:
        """Read until the source fails (its reason) or the camera closes (None)."""
        file = isinstance(self.config.source, str) and os.path.isfile(self.config.source)
        if file and self.start_frame + self.received > 0:
            cap.set(cv2.CAP_PROP_POS_FRAMES, self.start_frame + self.received)   # where the last visit left it
        fps = cap.get(cv2.CAP_PROP_FPS) if file else 0.0
        frame_farm_s = 1.0 / fps if 0.1 <= fps <= 1000 else 1.0 / FILE_FPS
        due = time.monotonic()
        while not self._stop.is_set():
            ok, image = cap.read()
            if self._stop.is_set():
                return None
            if not ok or image is None:
                if self.config.loop_file and self.received and cap.set(cv2.CAP_PROP_POS_FRAMES, 0):
                    continue
                if file and self.received:
                    self._ended = True
                    return f"{self.config.source!r}: the video file ended"
                return f"{self.config.source!r}: no frame (source gone or silent)"
            if file:                 # each frame at its time: a file is not a live source
                due = max(due + self.clock.wall(frame_farm_s), time.monotonic() - 1.0)
                if self._stop.wait(max(0.0, due - time.monotonic())):
                    return None
            self._arrived(image)
        return None

    def _arrived(self, image) -> None:
        t = self.clock.now()
        with self._cond:
            if self._down is not None:
                log.warning("%s: frames again from %r", self.name, self.config.source)
                self._down = None
            if self._newest is not None and self._newest.seq > self._returned:
                self.skipped += 1
            self.received += 1
            self._newest = Frame(t, image, self.received)
        self._tell()

    def _mark_down(self, why: str) -> None:
        with self._cond:
            first = self._down is None
            self._down = why
        if first:
            log.warning("%s: camera lost: %s", self.name, why)
        self._tell()

    def _tell(self) -> None:
        with contextlib.suppress(RuntimeError):          # the loop closed: nobody reads any more
            self._loop.call_soon_threadsafe(self._news.set)

    # --- read() on the loop ---------------------------------------------------------------------
    async def _read(self) -> Frame:
        deadline = time.monotonic() + self.config.read_timeout_s
        while True:
            self._news.clear()
            with self._cond:
                newest, down = self._newest, self._down
                if newest is not None and newest.seq > self._returned and down is None:
                    self._returned = newest.seq
                    return newest
            if down is not None:
                raise LinkDown(self.name, down)
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceTimeout(self.name, f"no frame from {self.config.source!r} in "
                                               f"{self.config.read_timeout_s:g} s")
            waiter = asyncio.ensure_future(self._news.wait())
            try:
                await asyncio.wait({waiter}, timeout=left)
            finally:
                waiter.cancel()


async def in_daemon_thread(fn, name: str):
    """``fn()`` on a daemon thread of its own, awaited: a blocking open (bounded by its timeout) that
    the process may leave behind when it ends, as asyncio's executor threads, joined at exit, are not."""
    loop = asyncio.get_running_loop()
    done = loop.create_future()

    def run() -> None:
        try:
            result, error = fn(), None
        except BaseException as exc:  # noqa: BLE001 - handed to the awaiting task as it is
            result, error = None, exc
        with contextlib.suppress(RuntimeError):        # the loop closed meanwhile: nobody waits
            loop.call_soon_threadsafe(_settle, done, result, error)
    threading.Thread(target=run, name=name, daemon=True).start()
    return await done


def _settle(future, result, error) -> None:
    if future.done():
        return
    if error is not None:
        future.set_exception(error)
    else:
        future.set_result(result)
