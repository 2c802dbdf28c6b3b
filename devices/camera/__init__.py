"""The tower camera that watches the pond-cleaning robot's float.

Interface: ``TowerCamera``. Backends, chosen by ``driver`` through ``BACKENDS``:
- ``capture``: any source OpenCV's ``cv2.VideoCapture`` reads — an RTSP or HTTP (MJPEG) URL of
               an IP camera, a video file, a device index — in a reader thread of its own.
- ``sim``:     the simulated camera (devices/sim/tower_camera.py): an MJPEG-over-HTTP server of
               the rendered pond, read through ``capture`` like any IP camera.

``read()`` always gives the newest frame, never a stale queue: a tracker that falls behind skips
frames (counted in ``skipped``) rather than steering from the past.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from devices.base import Device


@dataclass(frozen=True, slots=True, eq=False)
class Frame:
    """``t``: farm time at arrival; ``image``: BGR uint8 (h, w, 3); ``seq``: 1, 2, ... per frame
    received since open (a jump means frames were skipped)."""

    t: float
    image: np.ndarray
    seq: int


class TowerCamera(Device):
    kind = "tower_camera"

    async def read(self) -> Frame:
        """The newest frame not returned before; waits up to ``read_timeout_s`` (wall) for one.
        LinkDown when the source is gone (the reader keeps reconnecting with back-off, and
        ``read()`` works again once it is back); DeviceTimeout when it sends nothing in time."""
        if not self._opened or self._closed:
            raise RuntimeError(f"{self.name}: read() on a camera that is not open")
        return await self._read()

    skipped: int = 0
    """Frames that arrived and were replaced by a newer one before anyone read them."""

    @abc.abstractmethod
    async def _read(self) -> Frame: ...


BACKENDS = {
    "capture": "devices.camera.capture:CaptureCamera",
}
