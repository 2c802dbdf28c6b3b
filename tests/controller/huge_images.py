"""Image files whose headers declare more pixels than OpenCV reads (2^30, CV_IO_MAX_IMAGE_PIXELS):
OpenCV raises on them rather than returning None, and every command must still answer in one line."""
from __future__ import annotations

import zlib

import cv2
import numpy as np


def chunk(kind: bytes, body: bytes) -> bytes:
    """A PNG chunk (PNG spec, 5.3): length, type, data, CRC over type and data."""
    return len(body).to_bytes(4, "big") + kind + body + zlib.crc32(kind + body).to_bytes(4, "big")


def huge_png(width: int = 40000, height: int = 40000) -> bytes:
    """A PNG whose IHDR declares the size and whose IDAT holds ten rows of it (PNG spec, 11.2)."""
    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 2, 0, 0, 0])
    rows = zlib.compress(b"\0" * (1 + 3 * width) * 10)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", rows) + chunk(b"IEND", b"")


def huge_jpeg(side: int = 60000) -> bytes:
    """An 8x8 baseline JPEG whose frame header (SOF0) is made to declare side x side."""
    data = bytearray(cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes())
    sof = data.find(b"\xff\xc0")
    data[sof + 5:sof + 9] = side.to_bytes(2, "big") * 2
    return bytes(data)
