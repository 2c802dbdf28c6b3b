"""The stereo camera through OpenCV's VideoCapture: each source read by the tower camera's
``capture`` driver (devices/camera/capture.py: a reader thread per source keeping the newest frame,
reconnecting with back-off), opened at ``start()`` and closed at ``stop()``.

``layout``: ``pair`` — two sources, left then right, which must be hardware-synchronised (an
external trigger): the pair is the newest frame of each; ``side_by_side`` — one source, the left
view in the left half; ``rg`` — one source, the left view in the red channel and the right in the
green (the paper's grabber).
"""
from __future__ import annotations

import json
import os
from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from devices.camera.capture import CaptureCamera, SourceLink
from devices.camera.capture import Config as SourceConfig
from devices.stereo import StereoCamera, StereoPair
from vision.calib_file import CalibrationError, StereoCalibration, calibration_from_json


class Config(SourceLink):
    sources: list[str | int] = Field(min_length=1, max_length=2,
                                     description="RTSP/HTTP URLs, video files or device indices: [left, right], "
                                     "or one source carrying both views")
    layout: Literal["pair", "side_by_side", "rg"] = "pair"
    calib: str = Field(min_length=1, description="CALIB.json of the rig (fishfarm calibrate ...)")
    read_timeout_s: float = Field(5.0, gt=0, le=60, description="wall seconds without a frame = gone")

    @field_validator("sources")
    @classmethod
    def _some_sources(cls, sources: list[str | int]) -> list[str | int]:
        for i, source in enumerate(sources):
            if (isinstance(source, str) and not source.strip()) or (isinstance(source, int) and source < 0):
                raise ValueError(f"sources.{i}: {source!r} is no URL, video file or device index")
        return sources

    @field_validator("calib")
    @classmethod
    def _calib(cls, path: str) -> str:
        load_calibration(path)
        return path

    @model_validator(mode="after")
    def _layout_fits(self):
        want = 2 if self.layout == "pair" else 1
        if len(self.sources) != want:
            raise ValueError(f"layout {self.layout!r} takes {want} source{'s' if want > 1 else ''}, "
                             f"not {len(self.sources)}")
        return self


def load_calibration(path: str) -> StereoCalibration:
    """The rig's CALIB.json; ValueError naming the file and the fault."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except OSError as exc:
        raise ValueError(f"{path}: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise ValueError(f"{path}: not JSON ({exc})") from None
    except RecursionError:
        raise ValueError(f"{path}: not JSON (nested too deep)") from None
    try:
        return calibration_from_json(data)
    except CalibrationError as exc:
        raise ValueError(f"{path}: {exc}") from None


def split_pair(image: np.ndarray, layout: str) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) views of one frame carrying both."""
    if layout == "side_by_side":
        half = image.shape[1] // 2
        return image[:, :half], image[:, half:2 * half]
    if image.ndim != 3 or image.shape[2] < 3:
        raise ValueError("an RG frame is colour: left in red, right in green")
    return np.ascontiguousarray(image[..., 2]), np.ascontiguousarray(image[..., 1])


class CaptureStereo(StereoCamera):
    Config = Config

    def __init__(self, name: str, config: Config, clock: Any):
        super().__init__(name, config, clock)
        self.calibration = load_calibration(config.calib)
        self._cams: list[CaptureCamera] = []
        self._seq = 0
        # a video file goes on at each visit where the last one left it: played from its start
        # again, one survey measured its first fish twice
        self._resume: dict[int, int] = {}

    def _source_config(self, source) -> SourceConfig:
        c = self.config
        return SourceConfig(kind="tower_camera", driver="capture", source=source, api=c.api,
                            read_timeout_s=c.read_timeout_s, open_timeout_s=c.open_timeout_s,
                            reconnect_s=c.reconnect_s, ffmpeg_options=c.ffmpeg_options)

    async def _open(self) -> None:
        pass                                  # nothing streams until a survey starts

    async def _start(self) -> None:
        sides = ("left", "right") if len(self.config.sources) == 2 else ("both",)
        self._cams = [CaptureCamera(f"{self.name}/{side}", self._source_config(src), self.clock)
                      for side, src in zip(sides, self.config.sources, strict=True)]
        for i, cam in enumerate(self._cams):
            cam.start_frame = self._resume.get(i, 0)
        try:
            for cam in self._cams:
                await cam.open()
        except BaseException:
            await self._stop()
            raise

    async def _stop(self) -> None:
        cams, self._cams = self._cams, []
        for i, cam in enumerate(cams):
            await cam.close()
            if isinstance(cam.config.source, str) and os.path.isfile(cam.config.source):
                self._resume[i] = cam.position

    async def _read(self) -> StereoPair:
        frames = [await cam.read() for cam in self._cams]
        if len(frames) == 2:
            left, right = frames[0].image, frames[1].image
        else:
            left, right = split_pair(frames[0].image, self.config.layout)
        self._seq += 1
        return StereoPair(min(f.t for f in frames), left, right, self._seq)
