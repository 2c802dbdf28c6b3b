"""Images read by the commands through OpenCV, a fault named in one line.

``cv2.imdecode`` returns None for most files it cannot read, but raises for some (an image declaring
more than 2^30 pixels, OpenCV's CV_IO_MAX_IMAGE_PIXELS); every command that reads images goes
through here, so either way the user gets one line naming the file, not a traceback.
"""
from __future__ import annotations

import cv2
import numpy as np

from controller.errors import BadInput


def opencv_decode(data: bytes | np.ndarray, name: str, flags: int, expected: str) -> np.ndarray | None:
    """``cv2.imdecode`` of a file's bytes (None where OpenCV cannot read it); ``expected`` names
    the formats in the message of a file OpenCV refuses outright."""
    try:
        return cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error as exc:
        if "CV_IO_MAX_IMAGE_PIXELS" in str(exc):
            raise BadInput(name, None, "too large: over 2^30 pixels, OpenCV's limit "
                           "(CV_IO_MAX_IMAGE_PIXELS)") from None
        raise BadInput(name, None, f"not a readable image ({expected} expected; OpenCV: "
                       f"{getattr(exc, 'err', '') or 'error'})") from None
