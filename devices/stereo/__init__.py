"""The stereo camera pair the rail robot carries to a tank for a weight survey.

Interface: ``StereoCamera``. Backends, chosen by ``driver`` through ``BACKENDS``:
- ``capture``: OpenCV's ``cv2.VideoCapture`` sources (RTSP/HTTP URLs, device indices, files):
               two synchronised cameras (``layout = "pair"``), or one source carrying both views —
               side by side (``"side_by_side"``, as USB stereo cameras send them) or the paper's RG
               grabber frame (``"rg"``: left view in red, right in green).
- ``sim``:     the simulated pair on the carriage (devices/sim/stereo_camera.py): the survey
               renderer's fish of the tank under the carriage, served side by side as MJPEG over
               HTTP and read through ``capture`` like any IP camera.

The cameras stream only between ``start()`` and ``stop()`` (a survey stop): a camera nobody
surveys with costs neither bandwidth nor, in the simulator, rendering. ``calibration`` is the rig's
CALIB.json, loaded when the section is validated (a bad file is bad input, not a failed survey).
"""
from __future__ import annotations

import abc
import asyncio
from dataclasses import dataclass

import numpy as np

from devices.base import Device
from vision.calib_file import StereoCalibration


@dataclass(frozen=True, slots=True, eq=False)
class StereoPair:
    """``t``: farm time the pair arrived; ``left``/``right``: uint8 images of one instant;
    ``seq``: 1, 2, ... per pair received since ``start()`` (a jump means pairs were skipped)."""

    t: float
    left: np.ndarray
    right: np.ndarray
    seq: int


class StereoCamera(Device):
    kind = "stereo_camera"
    calibration: StereoCalibration

    @property
    def streaming(self) -> bool:
        return self._streaming

    _streaming: bool = False

    async def start(self) -> None:
        """Start streaming (the survey stop begins). LinkDown when the source cannot be opened.
        Starts and stops run one at a time, in the order asked: a second start while the first is
        still opening the sources waits for it (two at once opened the sources twice and the first
        streams were never closed: 209 reader threads and 6 GB in one probe's controller), and a
        stop asked meanwhile stops what that start opened."""
        if not self._opened or self._closed:
            raise RuntimeError(f"{self.name}: start() on a camera that is not open")
        async with self._power():
            if not self._streaming:
                await self._start()
                self._streaming = True

    async def stop(self) -> None:
        """Stop streaming; safe to call when not streaming."""
        async with self._power():
            if self._streaming:
                self._streaming = False
                await self._stop()

    def _power(self) -> asyncio.Lock:
        if self._power_lock is None:
            self._power_lock = asyncio.Lock()
        return self._power_lock

    _power_lock: asyncio.Lock | None = None

    async def read(self) -> StereoPair:
        """The newest pair not returned before; waits up to the backend's read timeout (wall).
        LinkDown when a source is gone, DeviceTimeout when it sends nothing in time."""
        if not self._streaming:
            raise RuntimeError(f"{self.name}: read() while not streaming (start() first)")
        return await self._read()

    async def _close(self) -> None:
        await self.stop()

    @abc.abstractmethod
    async def _start(self) -> None: ...

    @abc.abstractmethod
    async def _stop(self) -> None: ...

    @abc.abstractmethod
    async def _read(self) -> StereoPair: ...


BACKENDS = {
    "capture": "devices.stereo.capture:CaptureStereo",
}
