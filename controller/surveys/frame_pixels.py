"""A still's pixels made 8-bit for measuring, and its size read from its header before decoding.

Stills are decoded at their own depth (``cv2.IMREAD_ANYDEPTH``) and brought to 8 bits here.
A 10- or 12-bit camera stores its values LSB-aligned in a 16-bit PNG or TIFF (0-1023, 0-4095);
OpenCV's own 16 -> 8 conversion shifts by 8 bits, which left such a frame 0-15 grey: no fish, and
no word of it. A 16-bit still is scaled by its actual bit depth instead: the smallest 2^k - 1 (k >= 8)
at or above its largest value (but for its brightest 0.01 % of pixels: hot pixels), taken over both
views of a pair so that the two are scaled alike (patches are compared across them). A
floating-point still (a 32-bit TIFF) is read when its values lie in 0..1 (scaled by 255), else
refused naming the values it holds.

Size: a frame too big (or small) for the calibration is refused from its header, before an 8000x6000
pair is decoded (551 MB and 1.8 s only to be refused) -- through Pillow (matplotlib's dependency,
so always installed), which reads the header alone.
"""
from __future__ import annotations

import io
import math
import warnings
from pathlib import Path

import cv2
import numpy as np

from controller.errors import BadInput


def _bits(value: float) -> int:
    """The smallest k >= 8 with 2^k - 1 >= value."""
    return max(8, int(value).bit_length())


HOT_SHARE = 1e-4          # of a pair's pixels, the brightest, that do not set its bit depth (hot pixels)


def _top(wide: list[np.ndarray]) -> int:
    """The largest value of the 16-bit views but for their brightest ``HOT_SHARE`` of pixels: one hot
    pixel at 65535 in a 10-bit frame scaled the pair to 0-4 grey, and the survey found no fish."""
    counts = sum(np.bincount(img.ravel(), minlength=65536) for img in wide)
    spare = int(HOT_SHARE * counts.sum())              # pixels that may lie above the top
    above = np.cumsum(counts[::-1])                     # pixels at or above each value, from 65535 down
    return 65535 - int(np.searchsorted(above, spare, side="right"))


def to_8bit(images: list[np.ndarray], names: list[str]) -> list[np.ndarray]:
    """The images (one pair, or one RG frame) as uint8, 16-bit ones by their common bit depth and
    floating-point ones from 0..1 (module docstring). BadInput names a still that cannot be."""
    wide = [img for img in images if img.dtype == np.uint16]
    scale16 = 255.0 / (2 ** _bits(_top(wide)) - 1) if wide else 1.0
    out = []
    for img, name in zip(images, names, strict=True):
        if img.dtype == np.uint8:
            out.append(img)
        elif img.dtype == np.uint16:
            out.append(cv2.convertScaleAbs(img, alpha=scale16))          # rounds and saturates
        elif img.dtype.kind == "f":
            lo, hi = (float(np.min(img)), float(np.max(img))) if img.size else (0.0, 0.0)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo and hi <= 1.0):
                raise BadInput(name, None, f"a floating-point image with values {lo:g} to {hi:g}: "
                                           "0 to 1 expected (or an 8- or 16-bit image)")
            out.append(cv2.convertScaleAbs(img.astype(np.float32), alpha=255.0))
        else:
            raise BadInput(name, None, f"a {img.dtype.itemsize * 8}-bit {'signed ' if img.dtype.kind == 'i' else ''}"
                                       "integer image: 8- or 16-bit unsigned (or 0-1 floating-point) expected")
    return out


def header_size(source: str | bytes) -> tuple[int, int] | None:
    """(width, height) from an image file's header (a path or its bytes), without decoding it;
    None when Pillow cannot tell (the decoder then has its say)."""
    try:
        from PIL import Image
    except ImportError:                  # (matplotlib brings it; without it the decoded size is checked)
        return None
    try:
        return _pillow_size(Image, source)
    except Image.DecompressionBombError:
        # past twice its own bound Pillow will not even say the size: asked again without the bound
        # (a header read; what it declares is then refused, not decoded)
        saved, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
        try:
            return _pillow_size(Image, source)
        except Exception:  # noqa: BLE001 -- as below
            return None
        finally:
            Image.MAX_IMAGE_PIXELS = saved
    except Exception:  # noqa: BLE001 -- any file Pillow cannot open is left to OpenCV's decoder to name
        return None


def _pillow_size(Image, source) -> tuple[int, int]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # Pillow's decompression-bomb warning: the size is what we want
        with Image.open(io.BytesIO(source) if isinstance(source, bytes) else Path(source)) as im:
            return tuple(int(v) for v in im.size)


SAME_PICTURE = 0.8       # ``likeness`` above which two views are one picture twice (2026-12-05: two
                         # cameras' views 0.13 at most, the real chessboard set and rendered pairs; one
                         # picture twice 0.96 at least, JPEG'd again at quality 50)
BAND_EDGE = 12           # px (3 sigma of the wider blur)


def likeness(left: np.ndarray, right: np.ndarray) -> float | None:
    """Band-pass correlation of two views at zero shift, grey, at half scale: near 0 for two cameras'
    views (parallax moves their structure, their noise is their own), near 1 for one picture given
    twice however it was recompressed (a JPEG copy, the same clip in two containers, red = green).
    None when either view has next to no structure to compare (a uniform frame: lights off)."""
    bands = []
    for img in (left, right):
        g = img if img.ndim == 2 else img[..., 0] if img.shape[2] not in (3, 4) else cv2.cvtColor(
            img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
        if min(g.shape[:2]) >= 64:
            g = cv2.resize(g, (g.shape[1] // 2, g.shape[0] // 2), interpolation=cv2.INTER_AREA)
        g = g.astype(np.float32)
        # the border's own band (the blurs fold the picture there) left out: any two pictures share it
        band = (cv2.GaussianBlur(g, (0, 0), 1.0) - cv2.GaussianBlur(g, (0, 0), 4.0))[BAND_EDGE:-BAND_EDGE,
                                                                                     BAND_EDGE:-BAND_EDGE]
        if min(band.shape) < BAND_EDGE:
            return None                       # too small a picture to say
        bands.append(band)
    a, b = bands
    ea, eb = float(np.vdot(a, a)), float(np.vdot(b, b))
    if min(ea, eb) < 0.25 * a.size:          # band-pass RMS under half a grey level
        return None
    return float(np.vdot(a, b)) / math.sqrt(ea * eb)
