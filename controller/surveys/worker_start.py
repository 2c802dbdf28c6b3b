"""Imported by the survey's forkserver before it starts any worker (``set_forkserver_preload``):
a worker being started as its survey ends dies without a traceback.

A survey stopped by a signal while its workers start (the first seconds) unlinks the pool's
semaphores as it exits; a worker the forkserver is forking then fails to rebuild them
(``FileNotFoundError`` in multiprocessing/synchronize.py) or finds its parent's pipe closed
(``EOFError`` in spawn.py), and the forkserver printed that traceback after the survey's own
one line ("fishfarm: aborted"). Those two, raised there, are what a survey that has ended looks
like to a starting worker: it exits 1 quietly. Anything else is printed as before.
"""
from __future__ import annotations

import os
import sys
import traceback

_ENDED = {FileNotFoundError: "synchronize.py", EOFError: "spawn.py"}
_default = sys.excepthook


def _innermost_file(tb) -> str:
    frames = traceback.extract_tb(tb)
    return os.path.basename(frames[-1].filename) if frames else ""


def quiet_if_survey_ended(kind, value, tb) -> None:
    where = _ENDED.get(kind)
    if where is not None and _innermost_file(tb) == where:
        return
    _default(kind, value, tb)


sys.excepthook = quiet_if_survey_ended
