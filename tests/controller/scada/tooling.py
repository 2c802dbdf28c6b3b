"""mbpoll (Debian's Modbus master), installed by the test set-up when missing — never by hand."""
from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import tempfile

import pytest


def mbpoll() -> str:
    """The mbpoll binary: installed with apt-get when missing (as `make test` does); the test
    skips, saying why, only where apt cannot install it."""
    found = shutil.which("mbpoll")
    if found:
        return found
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        pytest.skip("mbpoll is not installed and apt-get cannot install it here (not root, or no apt)")
    # one installer at a time: pytest-xdist workers share the machine's dpkg lock
    with open(os.path.join(tempfile.gettempdir(), "fishfarm-mbpoll-install.lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not shutil.which("mbpoll"):
            env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
            r = subprocess.run(["apt-get", "install", "-y", "-q", "mbpoll"], capture_output=True, text=True, env=env)
            if r.returncode != 0:
                subprocess.run(["apt-get", "update", "-q"], capture_output=True, text=True, env=env)
                r = subprocess.run(["apt-get", "install", "-y", "-q", "mbpoll"], capture_output=True, text=True,
                                   env=env)
            if r.returncode != 0:
                pytest.skip(f"apt-get install mbpoll failed: {r.stderr.strip().splitlines()[-1:]}")
    return shutil.which("mbpoll")
