"""What travels between a survey and its vision workers over Zenoh (README, "Vision workers").

A **job** (the payload of a get on ``farm/{site}/worker/node/{id}/pair``) is binary:
``b"FFJ1"``, a 4-byte big-endian header length, a UTF-8 JSON header, then the encoded images
back to back (sizes in the header)::

    {"job": str, "frame": int, "where": str, "names": [str, ...], "sizes": [int, ...],
     "calib": sha256 hex of the calibration's canonical JSON, "setup": SurveySetup as JSON,
     "measure": "module:function"}

One image is an RG frame, two are left and right. Image files go as they lie on disk (the worker
decodes them exactly as ``read_pair`` would); decoded frames (video) go as BMP, lossless, so a
worker measures the very pixels the survey would have. BMP, not PNG: writing and reading it is a
copy (0.4 + 0.3 ms a 1280x960 colour view against PNG level 1's 66 + 21 ms, the survey process's
largest cost a pair); it is 2.4x the bytes, which loopback and a gigabit link carry (~17 such pairs
a second on gigabit, more than a few 2-core workers measure).

A **reply** is one JSON object: ``{"ok": true, "job", "frame", "worker", "fish": [...],
"timings": {...}, "warning"}`` or ``{"ok": false, "job", "kind", "error"}`` where ``kind`` is
``bad_input`` (the pair itself is at fault: the survey stops, as it would locally),
``calibration`` (the worker could not fetch the calibration its hash names), ``refused`` (the
worker measures with another function or speaks another version) or ``internal``. NaN may appear
in a reply (Python's JSON extension): both ends are ours, and a quality term may be undefined.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import struct

import cv2
import numpy as np

from controller.payload import parse_object
from controller.surveys.frames import PairJob, file_bytes
from vision.calib_file import StereoCalibration
from vision.survey_types import FishGeometry, FishMeasurement, SurveySetup

MAGIC = b"FFJ1"
_LEN = struct.Struct(">I")
HEADER_MAX = 1 << 20          # a header is a few hundred bytes: more is garbage, not a job
FRAME_FORMAT = ".bmp"         # a decoded frame on the wire (module docstring); any cv2.imdecode reads it
LENGTH_SLACK = 1e-6          # a length the vision kept at its bound reads so again, rounding aside


class WireError(ValueError):
    """A job or a reply that does not follow this format."""


# ---- calibration by content --------------------------------------------------------------

def calibration_bytes(calib: StereoCalibration) -> bytes:
    return json.dumps(calib.to_json(), sort_keys=True, separators=(",", ":")).encode()


def content_hash(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


# ---- setup ---------------------------------------------------------------------------------

def setup_to_json(setup: SurveySetup) -> dict:
    return dataclasses.asdict(setup)


def setup_from_json(data: dict) -> SurveySetup:
    try:
        geometry = FishGeometry(**data["geometry"])
        up, floor = data.get("up_world"), data.get("floor_mm")
        return SurveySetup(setup=data["setup"], mi_ref=float(data["mi_ref"]), c_ref=float(data["c_ref"]),
                           geometry=geometry, up_world=None if up is None else tuple(float(x) for x in up),
                           floor_mm=None if floor is None else float(floor))
    except (KeyError, TypeError, ValueError) as exc:
        raise WireError(f"setup: {exc}") from None


# ---- jobs ----------------------------------------------------------------------------------

def job_blobs(job: PairJob) -> tuple[tuple[bytes, ...], tuple[str, ...]]:
    """The encoded images of a job and the names its faults are reported under."""
    if job.left is not None:
        blobs = []
        for img in (job.left, job.right):
            ok, buf = cv2.imencode(FRAME_FORMAT, np.ascontiguousarray(img))
            if not ok:
                raise WireError(f"{job.where}: cannot encode as {FRAME_FORMAT[1:].upper()}")
            blobs.append(buf.tobytes())
        return tuple(blobs), (job.where, job.where)
    return tuple(file_bytes(p) for p in job.paths), tuple(job.paths)


def encode_job(header: dict, blobs: tuple[bytes, ...]) -> bytes:
    head = json.dumps({**header, "sizes": [len(b) for b in blobs]}, separators=(",", ":")).encode()
    return b"".join((MAGIC, _LEN.pack(len(head)), head, *blobs))


def decode_job(data: bytes) -> tuple[dict, tuple[bytes, ...]]:
    if len(data) < 8 or data[:4] != MAGIC:
        raise WireError("not a fishfarm job (bad magic)")
    (n,) = _LEN.unpack_from(data, 4)
    if n > HEADER_MAX or 8 + n > len(data):
        raise WireError("job header length out of range")
    try:       # as the override queryables read theirs: bounded nesting (a RecursionError is no reply)
        header = parse_object(data[8:8 + n])
    except ValueError as exc:
        raise WireError(f"job header: {exc}") from None
    sizes = header.get("sizes") if isinstance(header, dict) else None
    if (not isinstance(sizes, list) or len(sizes) not in (1, 2)
            or not all(isinstance(s, int) and s >= 0 for s in sizes) or 8 + n + sum(sizes) != len(data)):
        raise WireError("job image sizes do not match its length")
    for key, kind in (("job", str), ("frame", int), ("where", str), ("calib", str), ("measure", str),
                      ("names", list), ("setup", dict)):
        if not isinstance(header.get(key), kind):
            raise WireError(f"job header: {key} missing or not {kind.__name__}")
    blobs, at = [], 8 + n
    for s in sizes:
        blobs.append(data[at:at + s])
        at += s
    return header, tuple(blobs)


# ---- replies -------------------------------------------------------------------------------

def fish_to_json(fish: FishMeasurement) -> dict:
    return {"snout_mm": np.asarray(fish.snout_mm, float).tolist(), "fork_mm": np.asarray(fish.fork_mm, float).tolist(),
            "snout_px": np.asarray(fish.snout_px, float).tolist(), "fork_px": np.asarray(fish.fork_px, float).tolist(),
            "score": float(fish.score), "quality": fish.quality}


def fish_from_json(data: dict) -> FishMeasurement:
    try:
        arrays = {k: np.asarray(data[k], dtype=float) for k in ("snout_mm", "fork_mm", "snout_px", "fork_px")}
        quality = data.get("quality", {})
        if not isinstance(quality, dict):
            raise TypeError("quality is not an object")
        fish = FishMeasurement(score=float(data["score"]), quality=quality, **arrays)
    except (KeyError, TypeError, ValueError) as exc:
        raise WireError(f"fish: {exc}") from None
    if fish.snout_mm.shape != (3,) or fish.fork_mm.shape != (3,) or fish.snout_px.shape != (2, 2) \
            or fish.fork_px.shape != (2, 2):
        raise WireError("fish: points of the wrong shape")
    return fish


def encode_reply(reply: dict) -> bytes:
    return json.dumps(reply, separators=(",", ":")).encode()


def decode_reply(data: bytes, job_id: str, lengths_cm: tuple[float, float] | None = None) -> dict:
    """A reply to job ``job_id``, checked; WireError when it is not one. With ``lengths_cm`` (the
    species' plausible fork lengths, which the vision itself pairs snouts within), a fish outside
    them, or with a point not finite, makes it garbage: a worker that says so is faulty or not ours
    (a rogue reply of 100 m fish once planned a ration of 4.6e14 g)."""
    try:
        reply = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise WireError(f"reply is not JSON: {exc}") from None
    except (RecursionError, ValueError) as exc:       # nested past the parser's stack, a 5,000-digit number
        raise WireError(f"reply is not JSON we read: {type(exc).__name__}") from None
    if not isinstance(reply, dict) or not isinstance(reply.get("ok"), bool):
        raise WireError("reply is not an object with a boolean ok")
    if reply.get("job") != job_id:
        raise WireError(f"reply answers job {reply.get('job')!r}, not {job_id!r}")
    if reply["ok"]:
        if not isinstance(reply.get("fish"), list) or not isinstance(reply.get("timings", {}), dict):
            raise WireError("reply without a fish list")
        reply["fish"] = [fish_from_json(f) if isinstance(f, dict) else _not_fish() for f in reply["fish"]]
        if lengths_cm is not None:
            for fish in reply["fish"]:
                _plausible(fish, lengths_cm)
    elif not isinstance(reply.get("error"), str):
        raise WireError("refusal without an error")
    return reply


def _plausible(fish: FishMeasurement, lengths_cm: tuple[float, float]) -> None:
    length = fish.length_cm
    points = np.concatenate([fish.snout_mm, fish.fork_mm, fish.snout_px.ravel(), fish.fork_px.ravel()])
    if not (np.all(np.isfinite(points)) and math.isfinite(fish.score)):
        raise WireError("fish: a point or the score is not finite")
    lo, hi = lengths_cm
    if not lo * (1 - LENGTH_SLACK) <= length <= hi * (1 + LENGTH_SLACK):
        raise WireError(f"fish: {length:.6g} cm long, outside the species' {lo:g}-{hi:g} cm")


def _not_fish():
    raise WireError("fish entry is not an object")
