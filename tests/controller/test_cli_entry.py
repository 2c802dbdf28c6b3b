"""The ``fishfarm`` process's entry point (controller.cli.entry): what it sets before any command."""
from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest

# The lines a lost camera printed straight to the terminal, every reconnect, with no time stamp:
# OpenCV's ("[ WARN:0@0.049] global cap.cpp:212 open VIDEOIO(FFMPEG): ...") and FFmpeg's
# ("[tcp @ 0x5612...] Connection to tcp://127.0.0.1:5 failed: Connection refused")
NATIVE = ("[ WARN:", "[ERROR:", " @ 0x", "[OPENCV:FFMPEG")

# entry() as the fishfarm script runs it, its command replaced by one opening the given URLs
PROBE = """
import sys
from controller import cli

def command():
    import cv2
    for url in sys.argv[1:]:
        print(url, cv2.VideoCapture(url, cv2.CAP_FFMPEG).isOpened(), file=sys.stderr, flush=True)
    return 0

cli.main = command
cli.entry()
"""


def _refused_port() -> int:
    with socket.socket() as s:       # bound, never listening: a connection to it is refused
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _opening_refused_urls(**env: str) -> str:
    port = _refused_port()
    urls = [f"tcp://127.0.0.1:{port}", f"http://127.0.0.1:{port}/video.mjpg"]
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("OPENCV_", "FISHFARM_"))}
    done = subprocess.run([sys.executable, "-c", PROBE, *urls], capture_output=True, text=True, timeout=60,
                          env={**clean, **env})
    assert done.returncode == 0, done.stderr
    assert [line.split()[1] for line in done.stderr.splitlines() if line.startswith(tuple(urls))] == ["False"] * 2
    return done.stdout + done.stderr


def test_opencv_and_ffmpeg_print_nothing_of_their_own_from_a_fishfarm_process():
    printed = _opening_refused_urls()
    assert not [line for line in printed.splitlines() if any(mark in line for mark in NATIVE)], printed


@pytest.mark.parametrize(("variable", "value", "mark"), [("OPENCV_LOG_LEVEL", "WARNING", "[ WARN:"),
                                                         ("OPENCV_FFMPEG_LOGLEVEL", "16", "Connection refused")])
def test_a_user_who_asks_for_them_still_gets_them(variable, value, mark):
    assert mark in _opening_refused_urls(**{variable: value})
