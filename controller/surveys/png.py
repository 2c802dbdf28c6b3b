"""PNG stills decoded by libpng through imagecodecs, whose inflate is zlib-ng's.

Inflating is most of a PNG's cost: a 1280×960 colour still takes ~7.7 ms here against OpenCV's
~13.4 ms, and a survey of stills spends that twice a pair on cores the measuring needs. The plain
kinds (8-bit grey or RGB, not interlaced, no transparency, no EXIF orientation: what cameras and
OpenCV write) are returned as ``cv2.imdecode`` returns them, bit for bit (BGR order); any other
kind is left to OpenCV, so 16-bit, palette, alpha and rotated stills keep OpenCV's meaning.

A damaged plain PNG is named by libpng's own reason ("IDAT: CRC error") in one line, where OpenCV
would print libpng's line on stderr beside ours and say only that the file is unreadable. The other
kinds are not decoded here at all (their header says which they are), so none is decoded twice.
"""
from __future__ import annotations

import cv2
import numpy as np

SIGNATURE = b"\x89PNG\r\n\x1a\n"
GREY, RGB = 0, 2                     # IHDR colour types
MAX_PIXELS = 1 << 30                 # OpenCV's CV_IO_MAX_IMAGE_PIXELS default


class DamagedPNG(ValueError):
    """libpng refused the file; the message is its reason."""


def _has_chunk(data: bytes, kind: bytes) -> bool:
    """Whether the PNG holds a chunk of this kind (walking the chunks' headers: a search of the
    bytes would also find it inside compressed data)."""
    at = len(SIGNATURE)
    while at + 8 <= len(data):
        size, here = int.from_bytes(data[at:at + 4], "big"), data[at + 4:at + 8]
        if here == kind:
            return True
        if here == b"IEND":
            return False
        at += 12 + size
    return False


def decode_png(data: bytes, colour: bool) -> np.ndarray | None:
    """The still as ``cv2.imdecode(data, IMREAD_COLOR if colour else IMREAD_ANYCOLOR)`` gives it,
    or None when the file is a PNG kind left to OpenCV (or not a PNG at all).

    Raises DamagedPNG when libpng cannot decode it."""
    if not data.startswith(SIGNATURE) or len(data) < 33 or data[12:16] != b"IHDR":
        return None
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if width * height > MAX_PIXELS:
        return None                 # OpenCV refuses it by name; libpng would allocate it all
    depth, kind, interlace = data[24], data[25], data[28]
    # eXIf may rotate the picture (OpenCV applies its orientation); transparency (tRNS) comes
    # back as a fourth channel and fails the shape checks below
    if depth != 8 or interlace != 0 or kind not in (GREY, RGB) or _has_chunk(data, b"eXIf"):
        return None
    # ~50 ms to import: only a survey of PNG stills pays it
    import imagecodecs

    try:
        img = imagecodecs.png_decode(data)
    except imagecodecs.PngError as exc:
        raise DamagedPNG(str(exc) or "libpng could not decode it") from None
    if img.dtype != np.uint8:
        return None
    if kind == RGB and img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    if kind == GREY and img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if colour else img
    return None
