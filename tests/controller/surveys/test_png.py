"""PNG stills: the fast decoder gives what cv2.imdecode gives, bit for bit, for every PNG kind a
camera, OpenCV or Pillow writes, and takes the fast path for the plain ones."""
from __future__ import annotations

import io
import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image, PngImagePlugin

from controller.surveys.png import DamagedPNG, decode_png
from tests.controller.huge_images import chunk, huge_png

# PNG spec 2nd ed., 8.2: Adam7 passes as (x0, y0, dx, dy)
ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))


def handmade_png(img: np.ndarray, interlace: bool, extra: bytes = b"") -> bytes:
    """An 8-bit grey or RGB PNG written from the spec: filter 0 on every row, Adam7 when asked."""
    h, w = img.shape[:2]
    rgb = img[..., ::-1] if img.ndim == 3 else img        # PNG stores RGB, the arrays here are BGR
    passes = ADAM7 if interlace else ((0, 0, 1, 1),)
    raw = b"".join(b"\0" + row.tobytes() for x0, y0, dx, dy in passes for row in rgb[y0::dy, x0::dx]
                   if rgb[y0::dy, x0::dx].shape[1] > 0)
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2 if img.ndim == 3 else 0, 0, 0, int(interlace))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + extra + chunk(b"IDAT", zlib.compress(raw))
            + chunk(b"IEND", b""))


def pillow_png(img: np.ndarray, **kw) -> bytes:
    out = io.BytesIO()
    Image.fromarray(img[..., ::-1] if img.ndim == 3 else img).save(out, format="PNG", **kw)
    return out.getvalue()


def opencv_png(img: np.ndarray, level: int) -> bytes:
    return cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, level])[1].tobytes()


def as_opencv(data: bytes, colour: bool) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR if colour else cv2.IMREAD_ANYCOLOR)


images = st.builds(
    lambda h, w, c, seed: np.random.default_rng(seed).integers(0, 256, (h, w, 3) if c else (h, w), np.uint8),
    st.integers(1, 40), st.integers(1, 40), st.booleans(), st.integers(0, 2**32 - 1))


@settings(max_examples=60, deadline=None)
@given(img=images, level=st.integers(0, 9), colour=st.booleans())
def test_plain_pngs_from_opencv_take_the_fast_path_and_match_it(img, level, colour):
    data = opencv_png(img, level)
    got = decode_png(data, colour)
    assert got is not None
    want = as_opencv(data, colour)
    assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want)


@settings(max_examples=60, deadline=None)
@given(img=images, colour=st.booleans(), optimize=st.booleans(), chunks=st.booleans())
def test_plain_pngs_from_pillow_with_its_ancillary_chunks_match_opencv(img, colour, optimize, chunks):
    info = PngImagePlugin.PngInfo()
    if chunks:
        info.add_text("Software", "camera 1.0")
        info.add_itxt("Comment", "tank T3", zip=True)
    data = pillow_png(img, optimize=optimize, pnginfo=info, **({"gamma": 0.45455, "dpi": (72, 72)} if chunks else {}))
    got = decode_png(data, colour)
    assert got is not None and np.array_equal(got, as_opencv(data, colour))


# colour-management chunks a camera may write: neither OpenCV nor the fast path applies them
ANCILLARY = [b"",
             chunk(b"gAMA", struct.pack(">I", 45455)),                   # 1/2.2
             chunk(b"gAMA", struct.pack(">I", 100000)) + chunk(b"sRGB", b"\0"),
             chunk(b"sBIT", bytes([5, 6, 5])),
             chunk(b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000))]


@settings(max_examples=40, deadline=None)
@given(img=images, interlace=st.booleans(), colour=st.booleans(), extra=st.sampled_from(ANCILLARY))
def test_handmade_pngs_interlaced_or_not_read_as_opencv_reads_them(img, interlace, colour, extra):
    if img.ndim == 2 and extra.startswith(struct.pack(">I", 3) + b"sBIT"):
        extra = chunk(b"sBIT", bytes([5]))                              # grey: one significant-bits byte
    data = handmade_png(img, interlace, extra)
    got = decode_png(data, colour)
    assert (got is None) == interlace                 # Adam7 is left to OpenCV
    assert np.array_equal(as_opencv(data, colour), img if img.ndim == 3 or not colour
                          else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    if got is not None:
        assert np.array_equal(got, as_opencv(data, colour))


def _other_kinds(img: np.ndarray):
    grey = img[..., 0]
    yield "16-bit", opencv_png(img.astype(np.uint16) * 257 + 3, 3)
    yield "alpha", opencv_png(np.dstack([img, grey]), 3)
    yield "grey alpha", _pillow_mode(np.dstack([grey, grey]), "LA")
    yield "palette", _pillow_mode(img[..., ::-1], "P")
    yield "1-bit", _pillow_mode(grey > 128, "1")
    yield "transparent colour", handmade_png(img, False, chunk(b"tRNS", struct.pack(">HHH", 1, 2, 3)))
    exif = Image.Exif()
    exif[0x0112] = 6                                  # orientation: rotate 90 degrees to view
    yield "EXIF orientation", pillow_png(img, exif=exif.tobytes())


def _pillow_mode(arr: np.ndarray, mode: str) -> bytes:
    out = io.BytesIO()
    im = Image.fromarray(arr)
    (im.quantize(16) if mode == "P" else im.convert(mode) if im.mode != mode else im).save(out, format="PNG")
    return out.getvalue()


@pytest.mark.parametrize("colour", [False, True])
def test_every_other_kind_is_left_to_opencv(colour):
    img = np.random.default_rng(5).integers(0, 256, (23, 31, 3), np.uint8)
    for name, data in _other_kinds(img):
        assert decode_png(data, colour) is None, name


def test_orientation_is_why_an_exif_png_is_left_to_opencv():
    img = np.random.default_rng(6).integers(0, 256, (23, 31, 3), np.uint8)
    data = dict(_other_kinds(img))["EXIF orientation"]
    assert as_opencv(data, True).shape[:2] == (31, 23)      # OpenCV turned it


def test_a_png_declaring_more_pixels_than_opencv_reads_is_left_to_opencv_unallocated():
    # 40000 x 40000 x 3 would be 4.5 GB; OpenCV refuses over 2^30 pixels by name
    data = huge_png(40000, 40000)
    assert decode_png(data, False) is None
    with pytest.raises(cv2.error, match="CV_IO_MAX_IMAGE_PIXELS"):
        as_opencv(data, False)


def test_a_damaged_png_is_named_by_libpngs_reason_and_other_formats_pass_through():
    img = np.random.default_rng(7).integers(0, 256, (64, 64, 3), np.uint8)
    data = bytearray(opencv_png(img, 1))
    data[60:70] = bytes(b ^ 0x55 for b in data[60:70])       # inside IDAT: its CRC no longer holds
    with pytest.raises(DamagedPNG, match="CRC"):
        decode_png(bytes(data), False)
    for ext in (".jpg", ".bmp", ".tif"):
        assert decode_png(cv2.imencode(ext, img)[1].tobytes(), False) is None
    assert decode_png(b"\x89PNG\r\n\x1a\n", False) is None
