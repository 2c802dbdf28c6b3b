"""The packaged nets (``vision/models/*.onnx``) run by ONNX Runtime on one thread.

One thread a session: the survey runs one pair per core in worker processes, so a net's own
thread pool would only compete with the other workers. ONNX Runtime replaced OpenCV's dnn module
(2026-12-03): on these machines the fork net's 32 crops take 0.8 ms instead of 1.9 ms and the
keypoint net's 320x240 image 0.8 ms instead of 2.2 ms; their outputs differ by < 1e-5.
"""
from __future__ import annotations

from functools import lru_cache
from importlib import resources

import numpy as np
import onnxruntime as ort


@lru_cache(maxsize=4)
def session(model: str) -> ort.InferenceSession:
    """The session of a packaged model, by file name (loaded once a process)."""
    data = resources.files("vision.models").joinpath(model).read_bytes()
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.log_severity_level = 3             # errors only: no warnings about unused initialisers
    return ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])


def forward(model: str, x: np.ndarray, outputs: list[str] | None = None) -> list[np.ndarray]:
    """The named outputs (all, in the model's order, if None) of a model for one float32 input."""
    s = session(model)
    return s.run(outputs, {s.get_inputs()[0].name: np.ascontiguousarray(x, np.float32)})
