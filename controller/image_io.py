"""Images read by the commands through OpenCV, a fault named in one line.

``cv2.imdecode`` returns None for most files it cannot read, but raises for some (an image declaring
more than 2^30 pixels, OpenCV's CV_IO_MAX_IMAGE_PIXELS); every command that reads images goes
through here, so either way the user gets one line naming the file, not a traceback.

The codecs under OpenCV speak for themselves on the process's stderr (file descriptor 2, beyond
Python's reach): libpng's "libpng error: IDAT: CRC error", libtiff's and OpenCV's own log lines
for a TIFF or BMP cut short, and libjpeg's "Corrupt JPEG data: premature end of data segment" for
a JPEG damaged mid-scan, which OpenCV decodes anyway, the damage grey or smeared, for a survey to
measure (a fish 29.95 cm long instead of 25.31). What they write during a decode is caught: a
refusal names it in our one line, damage refuses the image, and anything else (a libpng warning
about a colour profile) is passed on as it came.
"""
from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import threading

import cv2
import numpy as np

from controller.errors import BadInput

# what the codecs say of a file they cannot read whole (libtiff's warnings, an unknown tag, are not that)
# (nor libjpeg's "extraneous bytes before marker", which webcams' MJPEG frames carry whole)
DAMAGE = re.compile(r"Corrupt JPEG data(?!: \d+ extraneous bytes)|Premature end of JPEG|Bogus|Not a JPEG"
                    r"|libpng error|imdecode_|[Uu]nexpected end|TIFF.*[Ee]rror|[Ee]rror.*TIFF")
_CAUGHT = threading.Lock()          # fd 2 is the process's: one capture at a time
_sink = None                        # the file fd 2 writes to meanwhile: one per process, emptied each time


@contextlib.contextmanager
def native_stderr():
    """What native code writes to file descriptor 2 meanwhile: the list holds it once the block
    is left. Where fd 2 cannot be redirected the block just runs and the list stays empty."""
    global _sink
    caught: list[str] = []
    with _CAUGHT:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError):
            yield caught
            return
        if _sink is None:       # (a new file each decode cost a BMP pair's decode ~25 %)
            _sink = tempfile.TemporaryFile()
        _sink.seek(0)
        _sink.truncate()
        os.dup2(_sink.fileno(), 2)
        try:
            yield caught
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            _sink.seek(0)
            caught.append(_sink.read().decode("utf-8", "replace"))


def _said(text: str) -> str:
    """A codec's line without OpenCV's log prefix ("[ WARN:0@1.2] global grfmt_tiff.cpp:123 f ")."""
    line = re.sub(r"^\[\s*\w+:[^\]]*\]\s*(global\s+\S+?(:\d+|\s+\(\d+\))\s+\S+\s+)?", "", text.strip())
    return line[:160]


def opencv_decode(data: bytes | np.ndarray, name: str, flags: int, expected: str) -> np.ndarray | None:
    """``cv2.imdecode`` of a file's bytes (None where OpenCV cannot read it); ``expected`` names
    the formats in the message of a file OpenCV refuses outright. An image its codec reports damaged
    is refused by name (module docstring)."""
    failed = None
    with native_stderr() as caught:
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
        except cv2.error as exc:
            img, failed = None, exc
    lines = [line for line in "".join(caught).splitlines() if line.strip()]
    if failed is not None:
        if "CV_IO_MAX_IMAGE_PIXELS" in str(failed):
            raise BadInput(name, None, "too large: over 2^30 pixels, OpenCV's limit (CV_IO_MAX_IMAGE_PIXELS)")
        raise BadInput(name, None, f"not a readable image ({expected} expected; OpenCV: "
                       f"{getattr(failed, 'err', '') or 'error'})")
    damage = [line for line in lines if DAMAGE.search(line)]
    if img is None and lines:
        raise BadInput(name, None, f"not a readable image ({expected} expected; its decoder: "
                                   f"{_said((damage or lines)[-1])})")
    if damage:
        raise BadInput(name, None, f"damaged image (its decoder: {_said(damage[0])})")
    if lines:
        sys.stderr.write("\n".join(lines) + "\n")
    return img
