"""Images whose codec complains on the process's stderr: refused in one line naming the file and
what the codec said, its own line not leaking beside ours; a damaged JPEG OpenCV would decode
anyway (the damage smeared) refused, not measured; whole images still read."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from controller.errors import BadInput
from controller.image_io import opencv_decode

RNG = np.random.default_rng(0)
PICTURE = cv2.GaussianBlur((RNG.random((240, 320, 3)) * 255).astype(np.uint8), (0, 0), 3)


def encoded(ext: str, img=PICTURE) -> bytes:
    ok, data = cv2.imencode(ext, img)
    assert ok
    return data.tobytes()


def zeroed_mid_scan(data: bytes) -> bytes:
    out = bytearray(data)
    mid = len(out) // 2
    out[mid:mid + 64] = bytes(64)
    return bytes(out)


def crc_broken(data: bytes) -> bytes:
    out = bytearray(data)
    out[len(out) // 2] ^= 0xFF
    return bytes(out)


DAMAGED = [
    ("mid.jpg", zeroed_mid_scan(encoded(".jpg")), "damaged image (its decoder: Corrupt JPEG data"),
    ("crc16.png", crc_broken(encoded(".png", PICTURE.astype(np.uint16) * 257)), "libpng error: IDAT"),
    ("cut.tif", encoded(".tiff")[:len(encoded(".tiff")) // 2], "TIFF"),
    ("cut.bmp", encoded(".bmp")[:len(encoded(".bmp")) // 2], "its decoder"),
    ("float.tif", encoded(".tiff", PICTURE.astype(np.float32)), "32-bit samples"),
]


@pytest.mark.parametrize("name, data, said", DAMAGED, ids=[d[0] for d in DAMAGED])
def test_what_the_codec_says_is_in_our_one_line_not_beside_it(capfd, name, data, said):
    with pytest.raises(BadInput) as refused:
        opencv_decode(data, name, cv2.IMREAD_ANYCOLOR, "PNG, JPEG, BMP or TIFF")
    message = str(refused.value)
    assert message.startswith(f"{name}: ") and said in message and "\n" not in message, message
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize("ext", [".jpg", ".png", ".bmp", ".tiff"])
def test_whole_images_are_read_as_opencv_reads_them(capfd, ext):
    data = encoded(ext)
    got = opencv_decode(data, "x" + ext, cv2.IMREAD_ANYCOLOR, "any")
    np.testing.assert_array_equal(got, cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_ANYCOLOR))
    assert capfd.readouterr().err == ""


def test_a_jpeg_with_extraneous_bytes_before_a_marker_is_whole_and_its_note_passed_on(capfd):
    """Webcams' MJPEG frames often carry stray bytes before a marker: libjpeg says so ("Corrupt JPEG
    data", which elsewhere means damage), the picture is whole: read, and the note passed on as it came."""
    data = encoded(".jpg")
    at = data.index(b"\xff\xdb")                      # the first quantisation table's marker
    padded = data[:at] + b"\x00\x11\x22" + data[at:]
    got = opencv_decode(padded, "cam.jpg", cv2.IMREAD_ANYCOLOR, "any")
    np.testing.assert_array_equal(got, cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_ANYCOLOR))
    assert capfd.readouterr().err == "Corrupt JPEG data: 3 extraneous bytes before marker 0xdb\n"


def test_the_codec_s_words_of_one_image_are_not_those_of_the_next(capfd):
    """One sink serves every decode of a process: what it caught is gone before the next."""
    with pytest.raises(BadInput, match="Corrupt JPEG data: premature end"):
        opencv_decode(DAMAGED[0][1], "mid.jpg", cv2.IMREAD_ANYCOLOR, "any")
    assert opencv_decode(encoded(".jpg"), "whole.jpg", cv2.IMREAD_ANYCOLOR, "any") is not None
    assert capfd.readouterr().err == ""
