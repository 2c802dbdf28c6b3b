"""Tests run from any directory: relative paths in them mean the repository root."""
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _at_repository_root(monkeypatch):
    monkeypatch.chdir(ROOT)


# The suite runs on two xdist workers (Makefile: --dist loadgroup): the grow-out, the longest run,
# on one, every other run after another on the other. Each run's timing is judged in farm time on
# its own clock, and the machine's stalls are excused by its own witness (hil_tests/stalls.py).
ALONE = {"test_growout.py"}


def pytest_collection_modifyitems(items):
    for item in items:
        item.add_marker(pytest.mark.xdist_group("alone" if item.path.name in ALONE else "farm"))
