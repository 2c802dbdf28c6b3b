"""Data from the shared folder beside the repository (../shared/data), for tests on real images.

Without it such tests skip, saying why. Where the folder must be there (a release check), set
``FISHFARM_REQUIRE_DATA`` (to anything but "", "0" or "false"): a missing folder then fails the
tests instead of passing quietly. A generic ``CI`` variable is not enough — a clean clone elsewhere
has no shared folder beside it, and that is not a broken checkout.
"""
from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
REQUIRE_VARS = ("FISHFARM_REQUIRE_DATA",)


def data_required(environ: Mapping[str, str] = os.environ) -> bool:
    return any(environ.get(var, "").strip().lower() not in ("", "0", "false") for var in REQUIRE_VARS)


def data_status(folder: Path, environ: Mapping[str, str] = os.environ,
                what: str = "real data") -> tuple[str, str]:
    """("present" | "skip" | "fail", reason) for a data folder tests need; ``what`` names it."""
    if folder.is_dir():
        return "present", ""
    reason = f"{what} absent: {folder}"
    if data_required(environ):
        return "fail", f"{reason} (required: {' or '.join(REQUIRE_VARS)} is set)"
    return "skip", reason


def needs_data(folder: Path, what: str = "real data") -> pytest.MarkDecorator:
    """Mark for a test on ``folder``: skips with the reason when the data may be absent; otherwise
    no-op, and the test calls ``require`` (directly or through a fixture) to fail loudly."""
    status, reason = data_status(folder, what=what)
    return pytest.mark.skipif(status == "skip", reason=reason)


def require(folder: Path, what: str = "real data") -> Path:
    """``folder``, or fail the test (skip when the data is optional)."""
    status, reason = data_status(folder, what=what)
    if status == "fail":
        pytest.fail(reason, pytrace=False)
    if status == "skip":
        pytest.skip(reason)
    return folder
