"""The simulated tower camera: an MJPEG-over-HTTP server of rendered frames, as an IP camera.

``GET /stream.mjpg`` (any path but ``/frame.jpg``) answers ``multipart/x-mixed-replace`` with one
JPEG part per frame; ``GET /frame.jpg`` one snapshot. The controller reads it with the real
``capture`` driver (cv2.VideoCapture over FFmpeg), so it cannot tell it from a camera on a mast.

One producer thread renders ``render(t_s) -> BGR uint8`` at farm time ``clock.now()`` every
1/``fps`` wall seconds (wall: a camera's frame rate is a property of the camera, and rendering
cannot run faster than the wall allows; at speed X the frames are X/fps farm seconds apart) and
encodes it once; every client is handed the newest JPEG, so a slow client skips frames instead
of queueing them. Nothing is rendered while no client watches. ``stop()`` ends every stream (the
clients see the connection close, as when a camera loses power).
"""
from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from devices.sections import validate_section

log = logging.getLogger(__name__)
BOUNDARY = "fishfarmframe"
SEND_BUFFER = 256 * 1024          # bytes: two 1280x720 pond frames


class SimTowerCameraParams(BaseModel):
    """farm.toml ``[sim.tower_camera]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    fps: float = Field(10.0, gt=0, le=120, description="frames per wall second")
    width: int = Field(1280, ge=64, le=4096)
    height: int = Field(720, ge=64, le=4096)
    jpeg_quality: int = Field(85, ge=10, le=100)


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    camera: SimTowerCamera


class _Handler(BaseHTTPRequestHandler):
    server: _Server

    def setup(self):
        super().setup()
        # a small send buffer: a client that falls behind blocks our write (and then gets the newest
        # frame) instead of the kernel queueing seconds of old ones for it
        self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)

    def log_message(self, fmt, *args):           # one line per request is noise on a farm log
        log.debug("tower camera: " + fmt, *args)

    def do_GET(self):  # noqa: N802 - http.server's name
        cam = self.server.camera
        if self.path.split("?")[0] == "/frame.jpg":
            jpeg = cam.snapshot()
            self.send_response(200)
            self.send_header("Content-Type", "image/jpeg")
            self.send_header("Content-Length", str(len(jpeg)))
            self.end_headers()
            self.wfile.write(jpeg)
            return
        self.send_response(200)
        self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={BOUNDARY}")
        self.send_header("Cache-Control", "no-cache")
        self.send_header("Connection", "close")
        self.end_headers()
        with contextlib.suppress(OSError):        # the client went away: its stream ends
            for jpeg in cam.frames():
                self.wfile.write(b"--%s\r\nContent-Type: image/jpeg\r\nContent-Length: %d\r\n\r\n"
                                 % (BOUNDARY.encode(), len(jpeg)))
                self.wfile.write(jpeg)
                self.wfile.write(b"\r\n")
                self.wfile.flush()


class SimTowerCamera:
    """``render(t_s)``: the picture at farm time ``t_s``. ``url``: what the ``capture`` driver opens."""

    def __init__(self, render: Callable[[float], np.ndarray], clock, params: SimTowerCameraParams | dict | None = None,
                 *, host: str = "127.0.0.1", port: int = 0, where: str = "farm.toml"):
        if not isinstance(params, SimTowerCameraParams):
            params = validate_section(SimTowerCameraParams, params or {}, where, "sim.tower_camera")
        self.params, self.render, self.clock = params, render, clock
        self.host, self._port = host, port
        self.rendered = 0                          # frames rendered and encoded
        self.render_walls: dict[int, float] = {}   # seq -> perf_counter when rendering began (last few)
        self._cond = threading.Condition()
        self._jpeg: bytes | None = None
        self._began = 0.0                          # perf_counter when the newest frame's rendering began
        self._seq = 0
        self._clients = 0
        self._stop = threading.Event()
        self._server: _Server | None = None
        self._threads: list[threading.Thread] = []

    @property
    def port(self) -> int:
        return self._server.server_address[1] if self._server is not None else 0

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/stream.mjpg"

    def start(self) -> None:
        self._stop.clear()
        self._server = _Server((self.host, self._port), _Handler)
        self._server.camera = self
        self._threads = [threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.05},
                                          name="sim-tower-camera-http", daemon=True),
                         threading.Thread(target=self._produce, name="sim-tower-camera-render", daemon=True)]
        for th in self._threads:
            th.start()

    def halt(self) -> None:
        """No more frames: the producer renders none after the one it is on, every stream ends."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    def stop(self, wait_s: float = 2.0) -> None:
        """Halt, close the server, and wait at most ``wait_s`` for each thread (they are daemons: a
        frame still rendering in C, a second and more for the survey cameras' pairs, is left to end
        with the process)."""
        self.halt()
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
        for th in self._threads:
            th.join(wait_s)
        self._threads = []

    # --- frames -----------------------------------------------------------------------------------
    def _encode(self) -> bytes:
        seq = self._seq + 1
        began = time.perf_counter()
        image = self.render(self.clock.now())
        want = (self.params.height, self.params.width, 3)
        if image.shape != want or image.dtype != np.uint8:
            raise ValueError(f"tower camera: rendered {image.shape} {image.dtype}, not {want} uint8")
        # full-resolution colour (4:4:4): 4:2:0 halves the chroma, and at 640x360 the blue disc on
        # the pond's far half is ~4 px across: smeared into the water, the float was found in 4 of
        # 41 frames there (37 of 41 at 4:4:4), and a robot stopped there stayed `lost` for good
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.params.jpeg_quality,
                                               cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444])
        if not ok:
            raise RuntimeError("tower camera: JPEG encoding failed")
        self.render_walls[seq] = began
        self.render_walls.pop(seq - 256, None)
        return buf.tobytes()

    def _produce(self) -> None:
        period = 1.0 / self.params.fps
        next_at = time.monotonic()
        while not self._stop.is_set():
            with self._cond:
                while self._clients == 0 and not self._stop.is_set():
                    self._cond.wait(0.1)
                    next_at = time.monotonic()
            if self._stop.is_set():
                return
            began = time.perf_counter()
            try:
                jpeg = self._encode()
            except Exception:  # noqa: BLE001 - a renderer bug must not kill the camera silently
                log.exception("tower camera: rendering failed")
                self._stop.wait(1.0)
                continue
            with self._cond:
                self._seq += 1
                self._jpeg, self._began = jpeg, began
                self.rendered += 1
                self._cond.notify_all()
            next_at = max(next_at + period, time.monotonic() - period)   # late: no burst to catch up
            self._stop.wait(max(0.0, next_at - time.monotonic()))

    def frames(self):
        """Each new JPEG made after the client came, as it is made, until the camera stops."""
        came = time.perf_counter()    # no frame whose rendering began before: a stale view
        with self._cond:
            seen = self._seq
            self._clients += 1
            self._cond.notify_all()
        try:
            while True:
                with self._cond:
                    while (self._seq == seen or self._began < came) and not self._stop.is_set():
                        seen = self._seq
                        self._cond.wait(0.5)
                    if self._stop.is_set():
                        return
                    seen, jpeg = self._seq, self._jpeg
                yield jpeg
        finally:
            with self._cond:
                self._clients -= 1

    def snapshot(self) -> bytes:
        return self._encode()
