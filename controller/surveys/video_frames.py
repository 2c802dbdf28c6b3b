"""Video input of a survey: two synchronised video files (left, right) or one RG video, decoded
in order in the survey's own process (controller/surveys/frames.py reads stills and one pair).
A video is checked as it goes: the two views alike in size and rate and not one picture twice,
the same length, and no shorter than its header declares."""
from __future__ import annotations

import os
import time
import warnings
from collections.abc import Iterator

import cv2

from controller.errors import BadInput
from controller.surveys.frames import PairJob, Source, _exists, check_two_files, check_two_views, split_rg


def _open_video(path: str) -> cv2.VideoCapture:
    _exists(path)
    # FFmpeg's own complaints ("moov atom not found") would precede our one-line error; a user
    # who wants them sets the variable. It is read when the first capture opens.
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    cap = cv2.VideoCapture(path)
    if not cap.isOpened():
        raise BadInput(path, None, "cannot open as a video")
    return cap


def _frame_count(cap: cv2.VideoCapture) -> int | None:
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    return n if n > 0 else None


def video_source(paths: tuple[str, ...], every: int = 1, max_frames: int | None = None,
                 sync_offset: int = 0) -> Source:
    """Two synchronised videos (left, right) or one RG video (a 1-tuple), decoded in order.
    ``sync_offset`` N: the right video's frame k + N shows the left's frame k (cameras started
    apart; N < 0: the left started later). Frames are numbered as the left video's."""
    if sync_offset and len(paths) != 2:
        raise BadInput("--sync-offset", None, "is for two videos (--video LEFT RIGHT)")
    if len(paths) == 2:
        check_two_files(*paths)
    caps = [_open_video(p) for p in paths]
    rates = [float(c.get(cv2.CAP_PROP_FPS) or 0.0) for c in caps]
    if len(caps) == 2 and min(rates) > 0 and abs(rates[1] - rates[0]) > 0.01 * rates[0]:
        # frame i of one is not frame i of the other: every pair would pair two moments
        for c in caps:
            c.release()
        raise BadInput(paths[1], None, f"{rates[1]:g} frames/s, but {paths[0]} is {rates[0]:g}: "
                                       "not synchronised frame by frame")
    fps = rates[0] or 25.0
    skips = [max(0, -sync_offset), max(0, sync_offset)][:len(caps)]
    counts = [_frame_count(c) for c in caps]
    for cap, path, skip in zip(caps, paths, skips, strict=True):
        _skip(caps, cap, path, skip)
    known = [c - skip for c, skip in zip(counts, skips, strict=True) if c is not None]
    total = None
    if len(known) == len(caps):
        total = -(-max(0, min(known)) // every)
        if max_frames is not None:
            total = min(total, max_frames)
    return Source(_video_jobs(caps, paths, every, max_frames, first=skips[0], offset=sync_offset, declared=counts),
                  total, fps, every=every)


def _skip(caps: list[cv2.VideoCapture], cap: cv2.VideoCapture, path: str, frames: int) -> None:
    """Pass over the first ``frames`` of a video (--sync-offset); one that has fewer is refused."""
    for k in range(frames):
        if not cap.grab():
            for c in caps:
                c.release()
            raise BadInput(path, "--sync-offset", f"skips {frames} frames, but the video has {k}")


def _still_format(path: str) -> str | None:
    """The format of a file Pillow reads as one still picture (PNG, JPEG...), else None. FFmpeg
    opens a still as a video of one frame at 25 frames/s: surveyed so, its fish were each one
    sighting, too few to count (0 fish, exit 0, where --pair counted them)."""
    try:
        from PIL import Image
    except ImportError:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as im:
                return str(im.format) if getattr(im, "n_frames", 1) == 1 else None
    except Exception:  # noqa: BLE001 -- whatever Pillow cannot read is no still of its formats
        return None


def _not_a_still(path: str, frames: int) -> None:
    """A "video" that held one frame and is a still image is refused as one (the survey's --pair reads it)."""
    fmt = _still_format(path) if frames == 1 else None
    if fmt is not None:
        raise BadInput(path, None, f"a still image ({fmt}), not a video: survey stills with --pair LEFT RIGHT "
                                   "or --rg FRAME")


def _check_whole(path: str, read: int, declared: int | None, done: int) -> None:
    """A video that ended after ``read`` frames, shorter than its header says, is refused: a file
    cut short (a copy interrupted, a recorder's disk full) whose last frame may be half decoded.
    A container that only estimates its count (from duration x rate) may say a frame or two more."""
    if declared is not None and read < declared - max(2, declared // 200):
        held = f"; --max-frames {done - 1} surveys the pairs before its end" if done > 1 else ""
        raise BadInput(path, None, f"ends at frame {read}, but its header declares {declared} frames: "
                                   f"cut short or damaged{held}")


def _video_jobs(caps: list[cv2.VideoCapture], paths: tuple[str, ...], every: int,
                max_frames: int | None, first: int = 0, offset: int = 0,
                declared: list[int | None] | None = None) -> Iterator[PairJob]:
    """Pairs from the left video's frame ``first`` on (numbered as the left's), the right's frame
    ``offset`` ahead of it; ``declared``: each video's frame count as its header gives it."""
    name = " + ".join(paths)
    i, done = first, 0
    try:
        while max_frames is None or done < max_frames:
            t0 = time.perf_counter()
            keep = (i - first) % every == 0
            # grab() skips the colour conversion of frames --every leaves out
            got = [c.read()[1] if keep else (True if c.grab() else None) for c in caps]
            ended = [g is None or g is False for g in got]
            if any(ended) and i == first:      # (whichever ended had none past --sync-offset's skip)
                raise BadInput(paths[ended.index(True)], None, "no frames" + (" after --sync-offset" if offset else ""))
            if any(ended):
                for k in range(len(caps)):
                    _not_a_still(paths[k], i - first + (0 if ended[k] else 1))
            if all(ended):
                for k, count in enumerate(declared or ()):
                    _check_whole(paths[k], i + (offset if k == 1 else 0), count, done)
                if max_frames is not None:
                    raise BadInput(name, "--max-frames", f"the video ends after {i} frames ({done} pairs), "
                                                         f"before --max-frames {max_frames}")
                return
            if any(ended):
                k = ended.index(True)
                own = i + (offset if k == 1 else 0)             # the frame in that video's own count
                if declared:            # one cut short: its last frame may be half decoded, not a sync fault
                    _check_whole(paths[k], own, declared[k], done)
                overlap = f"; --max-frames {done} surveys the pairs both hold" if done else ""
                raise BadInput(paths[k], None, f"ends at frame {own}, but {paths[1 - k]} goes on: the videos are "
                                               f"not the same length (not synchronised? --sync-offset N pairs the "
                                               f"right's frame k + N with the left's k{overlap})")
            if keep:
                warning = None
                if len(caps) == 1:
                    left, right, warning = split_rg(got[0], f"{paths[0]} frame {i}")
                else:
                    left, right = got
                    check_two_views(left, right, f"{paths[0]} frame {i}", f"{paths[1]} frame {i + offset}")
                yield PairJob(i, f"{name} frame {i}", left=left, right=right, read_s=time.perf_counter() - t0,
                              warning=warning)
                done += 1
            i += 1
    finally:
        for c in caps:
            c.release()
