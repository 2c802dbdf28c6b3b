"""The simulated tower camera read through the real ``capture`` driver: latency and frame rate.

For each size (1280x720, 960x540) and asked frame rate, the MJPEG twin (devices/sim/tower_camera.py)
serves frames whose top-left corner carries the frame's number in black and white blocks; the
``capture`` driver (cv2.VideoCapture, FFmpeg) reads them in this process, and each frame read is
matched by that number to the instant its rendering began. Figures:

- ``latency_ms``: render start -> ``read()`` returns it (p50, p90, max): render + JPEG encode + HTTP
  + FFmpeg demux/decode + the reader's hand-over;
- ``fps``: frames read per wall second; ``skipped``: frames the reader replaced before a read;
- ``render_ms``: the cost of the renderer alone (``pond``: the pond renderer with the float;
  ``noise``: a noise texture, JPEG's worst case), to tell it from the pipe.

The sim process hands the reader a small FFmpeg receive window (``RECV_WINDOW``), so a reader that
falls behind makes the server skip frames rather than the kernel queue them; the last two cases
show the worst-case frames with and without it.

Run: ``.venv/bin/python bench/bench_tower_camera.py``; prints one JSON object. Env:
``BENCH_CAMERA_SECONDS`` (per case, default 4).
"""
from __future__ import annotations

import asyncio
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from devices.camera.capture import CaptureCamera, Config  # noqa: E402
from devices.clock import ScaledClock  # noqa: E402
from devices.sim.tower_camera import SimTowerCamera  # noqa: E402
from devices.sim.world import RECV_WINDOW  # noqa: E402

BITS, CELL = 16, 16


def stamp(image: np.ndarray, n: int) -> None:
    for i in range(BITS):
        image[:CELL, i * CELL:(i + 1) * CELL] = 255 if n >> i & 1 else 0


def unstamp(image: np.ndarray) -> int:
    cells = image[2:CELL - 2, :BITS * CELL].reshape(CELL - 4, BITS, CELL, -1)[:, :, 2:CELL - 2]
    return sum(1 << i for i, v in enumerate(cells.mean(axis=(0, 2, 3))) if v > 127)


def renderer(kind: str, width: int, height: int):
    """``noise``: a noise texture (JPEG's worst case, nearly free to draw); ``pond``: the pond
    renderer (devices/sim/pond_view.py) with the float crossing it."""
    count = [0]
    if kind == "noise":
        water = np.random.default_rng(0).integers(40, 140, (height, width, 3), dtype=np.uint8)

        def draw(t_s):
            return np.roll(water, count[0] % 97, axis=1)
    else:
        from devices.sim.pond_view import FloatPose, PondScene, tower_view
        outline = [(0.0, 0.0), (20.0, 0.0), (20.0, 10.0), (0.0, 10.0)]
        scene = PondScene(tower_view(outline, width=width, height=height), outline, seed=0)

        def draw(t_s):
            return scene.render(t_s, FloatPose(2.0 + (count[0] % 400) * 0.04, 5.0, 0.3))

    def render(t_s: float) -> np.ndarray:
        count[0] += 1
        img = draw(t_s)
        stamp(img, count[0])
        return img
    return render


async def case(kind: str, width: int, height: int, fps: float, seconds: float,
               window: str | None = RECV_WINDOW) -> dict:
    clock = ScaledClock.real()
    cam = SimTowerCamera(renderer(kind, width, height), clock, {"fps": fps, "width": width, "height": height})
    cam.start()
    dev = CaptureCamera("tower", Config(kind="tower_camera", driver="capture", source=cam.url, api="ffmpeg",
                                        ffmpeg_options=window), clock)
    await dev.open()
    lat, n, t0 = [], 0, time.perf_counter()
    try:
        while time.perf_counter() - t0 < seconds:
            frame = await dev.read()
            arrived = time.perf_counter()
            began = cam.render_walls.get(unstamp(frame.image))
            if began is not None and n > 5:          # the first frames carry the connection's setup
                lat.append((arrived - began) * 1000)
            n += 1
        took = time.perf_counter() - t0
    finally:
        await dev.close()
        cam.stop()
    render = renderer(kind, width, height)
    t = time.perf_counter()
    for i in range(20):
        render(i * 0.04)
    lat = np.array(lat)
    return {"frames": kind, "size": f"{width}x{height}", "recv_window": window is not None,
            "fps_asked": fps, "fps": round(n / took, 1),
            "skipped": dev.skipped, "matched": int(lat.size),
            "latency_ms": {"p50": round(float(np.percentile(lat, 50)), 1),
                           "p90": round(float(np.percentile(lat, 90)), 1), "max": round(float(lat.max()), 1)},
            "render_ms": round((time.perf_counter() - t) / 20 * 1000, 2)}


async def main() -> dict:
    seconds = float(os.environ.get("BENCH_CAMERA_SECONDS", "4"))
    cases = [await case("pond", w, h, fps, seconds) for w, h in ((1280, 720), (960, 540)) for fps in (25.0, 60.0)]
    cases += [await case("noise", 1280, 720, 25.0, seconds, window) for window in (RECV_WINDOW, None)]
    return {"cases": cases, "load": os.getloadavg()[0]}


if __name__ == "__main__":
    from bench import no_arguments

    no_arguments(__doc__)
    print(json.dumps(asyncio.run(main())))
