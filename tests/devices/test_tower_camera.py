"""The tower camera's ``capture`` driver (cv2.VideoCapture over FFmpeg) reading the MJPEG twin."""
from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

from devices.camera import Frame
from devices.camera.capture import CaptureCamera, Config
from devices.clock import ManualClock
from devices.errors import BadInput, LinkDown
from devices.sim.tower_camera import SimTowerCamera

from .waits import until

W, H = 320, 192           # the smallest frames that exercise the pipe
BITS, CELL = 12, 16


def stamp(image, n):
    for i in range(BITS):
        image[:CELL, i * CELL:(i + 1) * CELL] = 255 if n >> i & 1 else 0


def unstamp(image) -> int:
    cells = image[2:CELL - 2, :BITS * CELL].reshape(CELL - 4, BITS, CELL, -1)[:, :, 2:CELL - 2]
    return sum(1 << i for i, v in enumerate(cells.mean(axis=(0, 2, 3))) if v > 127)


class Scene:
    """Renders frame n with n stamped in its corner and the farm time it was asked for noted."""

    def __init__(self):
        self.asked: list[float] = []
        y, x = np.mgrid[:H, :W]           # smooth: JPEG keeps it within a few levels
        wave = 90 + 30 * np.sin(x / 23.0) * np.cos(y / 17.0)
        self.water = np.dstack([wave + 20, wave, wave - 30]).astype(np.uint8)

    def __call__(self, t_s):
        self.asked.append(t_s)
        img = self.water.copy()
        stamp(img, len(self.asked))
        return img


def camera(url, clock, **kw) -> CaptureCamera:
    cfg = Config(kind="tower_camera", driver="capture", source=url, api="ffmpeg",
                 read_timeout_s=kw.pop("read_timeout_s", 2.0), reconnect_s=(0.05, 0.1), open_timeout_s=2.0, **kw)
    return CaptureCamera("tower", cfg, clock)


def serve(scene, clock, fps=50.0, port=0) -> SimTowerCamera:
    cam = SimTowerCamera(scene, clock, {"fps": fps, "width": W, "height": H}, port=port)
    cam.start()
    return cam


def test_frames_come_through_videocapture_in_order_stamped_at_arrival():
    async def main():
        clock, scene = ManualClock(t=5000.0), Scene()
        cam = serve(scene, clock)
        dev = camera(cam.url, clock)
        await dev.open()
        frames: list[Frame] = []
        for i in range(12):
            clock.t = 5000.0 + i                      # farm time moves between reads
            frames.append(await dev.read())
        await dev.close()
        await dev.close()                              # safe twice
        cam.stop()
        return scene, frames
    scene, frames = asyncio.run(main())
    for f in frames:
        assert f.image.shape == (H, W, 3) and f.image.dtype == np.uint8
        n = unstamp(f.image)
        assert 1 <= n <= len(scene.asked)
        # the picture is the rendered one (JPEG aside), stamp and all
        ref = scene.water.copy()
        stamp(ref, n)
        assert np.abs(f.image.astype(int) - ref).mean() < 4
    seqs = [f.seq for f in frames]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    numbers = [unstamp(f.image) for f in frames]
    assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)
    # stamped with the farm time at arrival: never before the read that could see it was set up
    assert all(5000.0 <= f.t <= 5011.0 for f in frames)


def test_read_gives_the_newest_frame_never_a_queue():
    async def main():
        clock, scene = ManualClock(), Scene()
        cam = serve(scene, clock, fps=40.0)
        dev = camera(cam.url, clock)
        await dev.open()
        first = await dev.read()
        await until(lambda: dev.received >= first.seq + 6)      # six more arrived unread
        newest = await dev.read()
        skipped = dev.skipped
        await dev.close()
        cam.stop()
        return first, newest, skipped
    first, newest, skipped = asyncio.run(main())
    assert newest.seq >= first.seq + 6
    assert unstamp(newest.image) >= unstamp(first.image) + 6
    assert skipped >= 5


def test_the_server_dying_is_link_down_and_its_return_is_recovery():
    async def main():
        clock, scene = ManualClock(), Scene()
        cam = serve(scene, clock)
        port = cam.port
        dev = camera(cam.url, clock, read_timeout_s=1.0)
        await dev.open()
        await dev.read()
        cam.stop()
        deadline = time.monotonic() + 5.0
        with pytest.raises(LinkDown):
            while time.monotonic() < deadline:
                await dev.read()                          # the frames still in flight, then LinkDown
        with pytest.raises(LinkDown):                     # and it stays down while nothing serves
            await dev.read()
        back = serve(scene, clock, port=port)
        deadline = time.monotonic() + 10.0
        frame = None
        while frame is None:
            try:
                frame = await dev.read()
            except LinkDown:
                assert time.monotonic() < deadline, "no recovery"
                await asyncio.sleep(0.02)
        rendered_before = len(scene.asked)
        await until(lambda: dev.received > frame.seq)
        after = await dev.read()
        await dev.close()
        back.stop()
        return frame, after, rendered_before, dev.reconnects
    frame, after, rendered_before, reconnects = asyncio.run(main())
    assert after.seq > frame.seq and unstamp(after.image) >= unstamp(frame.image)
    assert reconnects >= 1


def test_a_still_scene_s_identical_frames_are_frames():
    """A calm pond, noise reduction, the simulator with noise 0: the same picture again is a healthy
    camera's (dropped as "frozen" for a day, a docked cleaner faulted within 2 s and could not be
    started: controller/cleaning/picture.py judges a frozen picture by the robot's thrust)."""
    async def main():
        clock, scene = ManualClock(t=100.0), Scene()
        still = scene.water.copy()
        cam = serve(lambda t: still.copy(), clock, fps=40.0)
        dev = camera(cam.url, clock, read_timeout_s=1.0)
        await dev.open()
        frames = [await dev.read() for _ in range(10)]
        await dev.close()
        cam.stop()
        return frames
    frames = asyncio.run(main())
    assert [f.seq for f in frames] == sorted({f.seq for f in frames})
    assert all(np.array_equal(f.image, frames[0].image) for f in frames)


def test_ffmpeg_options_hold_for_their_own_open_only(monkeypatch):
    monkeypatch.delenv("OPENCV_FFMPEG_CAPTURE_OPTIONS", raising=False)

    async def main():
        clock, scene = ManualClock(), Scene()
        cam = serve(scene, clock)
        dev = camera(cam.url, clock, ffmpeg_options="recv_buffer_size;131072")
        await dev.open()
        frame = await dev.read()
        await dev.close()
        cam.stop()
        return frame
    assert asyncio.run(main()).image.shape == (H, W, 3)
    assert "OPENCV_FFMPEG_CAPTURE_OPTIONS" not in os.environ


def test_a_source_that_is_not_there_is_link_down_on_open():
    async def main():
        dev = camera("http://127.0.0.1:9/stream.mjpg", ManualClock())
        with pytest.raises(LinkDown):
            await dev.open()
        await dev.close()
        await dev.close()
    asyncio.run(main())


def test_snapshot_and_nothing_rendered_without_a_client():
    clock, scene = ManualClock(t=42.0), Scene()
    cam = serve(scene, clock, fps=100.0)
    try:
        time.sleep(0.05)                                # no client: the producer idles
        assert scene.asked == []
        with urllib.request.urlopen(f"http://127.0.0.1:{cam.port}/frame.jpg", timeout=5) as r:
            assert r.headers["Content-Type"] == "image/jpeg"
            img = cv2.imdecode(np.frombuffer(r.read(), np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (H, W, 3) and unstamp(img) == 1 and scene.asked == [42.0]
    finally:
        cam.stop()


def test_a_blue_dot_a_few_pixels_across_keeps_its_colour():
    # the float's blue disc on the far side of a 640x360 view is ~4 px: 4:2:0 chroma smeared it
    # into the water (a float unseen there for good); the snapshot keeps colour at full resolution
    clock = ManualClock(t=1.0)
    water = np.full((H, W, 3), (66, 96, 81), np.uint8)
    cv2.circle(water, (160, 96), 2, (223, 164, 61), -1)             # BGR: the renderer's blue disc

    def scene(t_s):
        return water.copy()
    cam = serve(scene, clock)
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{cam.port}/frame.jpg", timeout=5) as r:
            img = cv2.imdecode(np.frombuffer(r.read(), np.uint8), cv2.IMREAD_COLOR)
        hue, sat, _ = cv2.cvtColor(img[95:98, 159:162], cv2.COLOR_BGR2HSV).reshape(-1, 3).mean(axis=0)
        assert 92 <= hue <= 132 and sat >= 100                       # inside FloatParams' blue band
    finally:
        cam.stop()


def test_params_are_checked_by_name():
    with pytest.raises(BadInput, match="sim.tower_camera.fsp: unknown key"):
        SimTowerCamera(Scene(), ManualClock(), {"fsp": 10})
    with pytest.raises(ValueError):
        Config(kind="tower_camera", driver="capture", source=0, api="directshow")


def test_a_new_client_never_gets_a_frame_rendered_before_it_came():
    """The survey cameras stream per visit: a view left from the last stream would be another tank's."""
    async def main():
        clock, scene = ManualClock(), Scene()
        cam = serve(scene, clock, fps=20.0)
        dev = camera(cam.url, clock)
        await dev.open()
        await dev.read()
        await dev.close()
        await until(lambda: cam._clients == 0, what="the first client gone")
        rendered = len(scene.asked)
        again = camera(cam.url, clock)
        await again.open()
        first = await again.read()
        await again.close()
        cam.stop()
        return rendered, unstamp(first.image)
    rendered, first = asyncio.run(main())
    assert first > rendered


def test_a_frame_whose_rendering_began_before_the_client_came_is_not_its_first():
    """A frame still being rendered when a new stream opens shows the scene of before it opened."""
    class SlowScene(Scene):
        def __init__(self):
            super().__init__()
            self.began: list[float] = []

        def __call__(self, t_s):
            self.began.append(time.perf_counter())
            time.sleep(0.15)                      # rendering takes a while: the next client comes meanwhile
            return super().__call__(t_s)

    async def main():
        clock, scene = ManualClock(), SlowScene()
        cam = serve(scene, clock, fps=50.0)
        dev = camera(cam.url, clock)
        await dev.open()
        await dev.read()
        await until(lambda: len(scene.began) > len(scene.asked), what="a rendering under way")
        await dev.close()
        came = time.perf_counter()
        again = camera(cam.url, clock)
        await again.open()
        first = await again.read()
        await again.close()
        cam.stop()
        return scene, came, unstamp(first.image)
    scene, came, first = asyncio.run(main())
    assert scene.began[first - 1] >= came


def _clip(path, frames: int, fps: float) -> None:
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (W, H))
    scene = Scene()
    for i in range(frames):
        out.write(scene(i))
    out.release()


@pytest.mark.parametrize("loop_file", [False, True])
def test_a_video_file_plays_at_its_own_frame_rate_and_ends_for_good(tmp_path, loop_file):
    """A probe's 30 s clip was decoded in 0.8 s (the float moved thirty times too fast), then
    reopened and replayed at its end, lost and back every second, steering on old footage."""
    from devices.clock import ScaledClock
    clip = tmp_path / "dock.avi"
    _clip(clip, frames=12, fps=10.0)
    clock = ScaledClock.starting(2.0)              # 0.1 farm s a frame: 50 ms of wall

    async def main():
        dev = camera(str(clip), clock, loop_file=loop_file)
        await dev.open()
        seen = []
        try:
            while len(seen) < 30:
                try:
                    f = await dev.read()
                except LinkDown as exc:
                    return seen, str(exc), dev
                seen.append((f.seq, f.t, unstamp(f.image)))
            return seen, None, dev
        finally:
            await asyncio.sleep(0.3)                # what a reconnect would take (reconnect_s 0.05, 0.1)
            received = dev.received
            await dev.close()
            dev.received_after = received
    seen, ended, dev = asyncio.run(main())
    (s0, t0, _), (s1, t1, _) = seen[0], seen[-1]
    per_frame = (t1 - t0) / (s1 - s0)
    assert per_frame == pytest.approx(0.1, rel=0.35), seen      # the clip's own 10 fps, in farm time
    if loop_file:
        assert ended is None and [n for _, _, n in seen[:24]] == list(range(1, 13)) * 2
    else:
        assert [n for _, _, n in seen] == list(range(1, len(seen) + 1)) and len(seen) >= 10
        assert "the video file ended" in ended
        assert dev.received_after == 12                       # never reopened: no frame came again


STALLED = """
import asyncio, socket, sys, threading, time
import cv2, numpy as np
from devices.camera.capture import CaptureCamera, Config
from devices.clock import ManualClock

READ_TIMEOUT_S = float(sys.argv[1])
jpeg = cv2.imencode(".jpg", np.full((48, 64, 3), 120, np.uint8))[1].tobytes()
srv = socket.socket()
srv.bind(("127.0.0.1", 0))
srv.listen()
held = []

def serve():
    while True:
        conn, _ = srv.accept()
        held.append(conn)                      # kept open, never written to again: a stalled stream
        conn.recv(4096)
        conn.sendall(b"HTTP/1.0 200 OK\\r\\nContent-Type: multipart/x-mixed-replace; boundary=f\\r\\n\\r\\n")
        for _ in range(3):
            head = b"--f\\r\\nContent-Type: image/jpeg\\r\\nContent-Length: %d\\r\\n\\r\\n" % len(jpeg)
            conn.sendall(head + jpeg + b"\\r\\n")
threading.Thread(target=serve, daemon=True).start()

async def main():
    cfg = Config(kind="tower_camera", driver="capture", source=f"http://127.0.0.1:{srv.getsockname()[1]}/s.mjpg",
                 api="ffmpeg", read_timeout_s=READ_TIMEOUT_S, open_timeout_s=5.0, reconnect_s=(0.05,))
    cam = CaptureCamera("tower", cfg, ManualClock())
    await cam.open()
    await cam.read()
    await asyncio.sleep(0.5)                     # the reader is now inside a read that waits
    try:
        await asyncio.wait_for(cam.close(), 1.0)  # a stop gives it a moment, no more
    except TimeoutError:
        pass

asyncio.run(main())
print("closed", flush=True)
"""


def test_a_camera_closed_on_a_stalled_stream_does_not_hold_the_process_at_exit():
    """A stop while the survey camera's stream stalled: the stop said "stopped in 0.54 s", then
    the interpreter waited for asyncio's executor thread joining the reader (read_timeout_s + 2, up
    to 62 s) and the stop's watchdog ended it, exit 70. The process now ends when its work does."""
    read_timeout_s = 20.0
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", STALLED, str(read_timeout_s)], capture_output=True, text=True,
                       timeout=120, cwd=str(Path(__file__).resolve().parents[2]))
    took = time.monotonic() - t0
    assert r.returncode == 0 and "closed" in r.stdout, (r.stdout, r.stderr)
    assert took < 0.5 * read_timeout_s, took            # it waited the read's timeout and more
