"""``fishfarm track``: replay tower camera frames through the controller's own float detection and
tracking, offline.

    fishfarm track --frames DIR --tower TOWER.json --json OUT.json [--lost-after S]

``DIR/frames.csv``: header ``frame,t_s,file``, one row per frame in time order (any origin, any
rate, gaps allowed); ``file`` is a colour image (PNG) relative to DIR, of any size. TOWER.json:
``{"H": 3x3}`` mapping pixel (u, v, 1) to pond (x_m, y_m, 1). OUT.json: ``{"track": [{"t_s",
"x_m", "y_m", "heading_rad", "state", "frame", "std_m", "speed_m_s", "confidence"}]}``, one entry a
frame; state "tracking", "predicted" (coasting through a dropout) or "lost" (position null). A
frame with no float in it is a dropout, not an error.

Frames go one at a time through ``vision.float_track.track_frame``, the very call the cleaner's
coordinator makes on the live camera. Bad input exits 2 with one line naming the file and the
fault (frames.csv: the line and the column), before anything is written.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import click
import numpy as np

from controller.cli.csvio import _read_text as read_text
from controller.cli.csvio import number
from controller.cli.params import Finite
from controller.errors import BadInput
from vision.calib_file import MAX_IMAGE_PX

HEADER = ("frame", "t_s", "file")
T_MAX_S = 1e11          # seconds either side of the origin (3,000 years): a time beyond is no time
DET_TOL = 1e-12        # |det H| / |H|^3 under which H counts as singular (as vision.tower)


def load_tower(path: str) -> np.ndarray:
    """H (3x3, finite, invertible) from TOWER.json; BadInput naming the fault."""
    return load_tower_file(path)[0]


def load_tower_file(path: str) -> tuple[np.ndarray, tuple[int, int] | None]:
    """(H, the (width, height) of the frames it was fitted to, or None where TOWER.json does not say)."""
    doc = _tower_doc(path)
    size = doc.get("image_size")
    if size is not None and not (isinstance(size, list) and len(size) == 2 and all(
            isinstance(v, int) and not isinstance(v, bool) and 0 < v <= MAX_IMAGE_PX for v in size)):
        raise BadInput(path, "image_size", f"expected [width, height] in whole pixels (1..{MAX_IMAGE_PX})")
    return _tower_h(path, doc), None if size is None else (size[0], size[1])


def _tower_doc(path: str) -> dict:
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BadInput(path, None, "no such file") from None
    except IsADirectoryError:
        raise BadInput(path, None, "is a directory, expected TOWER.json") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BadInput(path, None, f"not JSON: {exc}") from None
    except OSError as exc:
        raise BadInput(path, None, f"cannot read: {exc.strerror or exc}") from None
    if not isinstance(doc, dict) or "H" not in doc:
        raise BadInput(path, "H", 'missing (expected {"H": 3x3})')
    return doc


def _tower_h(path: str, doc: dict) -> np.ndarray:
    rows = doc["H"]
    # numbers only: numpy would read "1.0" and true as 1.0
    if not (isinstance(rows, list) and all(isinstance(r, list) for r in rows)
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for r in rows for v in r)):
        raise BadInput(path, "H", "expected a 3x3 array of numbers")
    try:
        H = np.array(rows, dtype=float)
    except (TypeError, ValueError):
        raise BadInput(path, "H", "expected a 3x3 array of numbers") from None
    if H.shape != (3, 3):
        raise BadInput(path, "H", f"expected a 3x3 array of numbers, got shape {H.shape}")
    if not np.all(np.isfinite(H)):
        raise BadInput(path, "H", "a value is not a finite number")
    scale = float(np.abs(H).max())
    if scale > 0:
        H = H / scale          # a homography is defined up to scale: 1e120 x H is H (and no overflow)
    if scale == 0 or abs(np.linalg.det(H)) <= DET_TOL * np.linalg.norm(H) ** 3:
        raise BadInput(path, "H", "singular: not a homography (it maps the image onto a line or a point)")
    return H


def read_frames(folder: str) -> list[tuple[int, float, Path, int]]:
    """(frame, t_s, image path, line) of each row of DIR/frames.csv; BadInput at the first fault."""
    d = Path(folder)
    if not d.is_dir():
        raise BadInput(folder, None, "no such directory" if not d.exists() else "not a directory")
    path = d / "frames.csv"
    where = str(path)
    reader = csv.reader(read_text(path).splitlines())
    header = next(reader, None)
    if header is None:
        raise BadInput(where, None, f"empty file (expected header '{','.join(HEADER)}')")
    if tuple(c.strip() for c in header) != HEADER:
        raise BadInput(where, "header", f"expected '{','.join(HEADER)}', found '{','.join(header)}'")
    rows, prev, seen = [], -math.inf, {}
    for lineno, cells in enumerate(reader, start=2):
        if not "".join(cells).strip():
            continue
        if len(cells) != len(HEADER):
            raise BadInput(where, f"line {lineno}", f"{len(cells)} fields, expected {len(HEADER)}")
        frame = _frame_number(cells[0], where, lineno)
        if frame in seen:          # OUT.json names each entry by its frame: two would be one
            raise BadInput(where, f"line {lineno}, column frame", f"frame {frame} again (line {seen[frame]})")
        seen[frame] = lineno
        t = number(cells[1], where, lineno, "t_s")
        if abs(t) > T_MAX_S:             # the filter's step to the power of 4 overflowed from ~1e77
            raise BadInput(where, f"line {lineno}, column t_s", f"{cells[1].strip()}: beyond {T_MAX_S:g} s, "
                                                                "not a time in seconds")
        if t < prev:
            raise BadInput(where, f"line {lineno}, column t_s",
                           f"{cells[1].strip()} is earlier than the row before ({prev:g}): rows must be in time order")
        name = cells[2].strip()
        if not name:
            raise BadInput(where, f"line {lineno}, column file", "empty")
        bad = next((c for c in name if not c.isprintable()), None)
        if bad is not None:          # a NUL is no file name the system takes (it was a ValueError, exit 1)
            raise BadInput(where, f"line {lineno}, column file", f"unprintable character {bad!r} in {name!r}")
        rows.append((frame, t, d / name, lineno))
        prev = t
    return rows


def _frame_number(cell: str, where: str, lineno: int) -> int:
    """A frame number, exactly: digits are read as an integer (as a float, 99999999999999999999999
    came back 99999999999999991611392); a number written otherwise must be a whole one within a
    float's exact integers."""
    text = cell.strip()
    if text.isascii() and text.removeprefix("+").isdigit():
        return int(text)
    frame = number(cell, where, lineno, "frame")
    if frame != int(frame) or frame < 0 or frame > 2 ** 53:
        raise BadInput(where, f"line {lineno}, column frame", f"not a frame number: {text!r}")
    return int(frame)


def read_image(path: Path, where: str) -> np.ndarray:
    import cv2

    from controller.image_io import opencv_decode
    if not path.is_file():
        raise BadInput(str(path), None, f"no such file ({where})")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BadInput(str(path), None, f"cannot be read: {exc.strerror or exc} ({where})") from None
    try:
        image = opencv_decode(data, str(path), cv2.IMREAD_UNCHANGED, "PNG")
    except BadInput as exc:                   # what the codec said, and where the frame is listed
        said = str(exc).removeprefix(f"{path}: ")
        if said.startswith("too large"):
            raise
        raise BadInput(str(path), None, f"cannot read it as an image ({where}): {said}") from None
    if image is None or image.size == 0:
        raise BadInput(str(path), None, f"cannot read it as an image ({where})")
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 2 or image.shape[2] == 1 or (np.array_equal(image[..., 0], image[..., 1])
                                                   and np.array_equal(image[..., 1], image[..., 2])):
        raise BadInput(str(path), None, f"a grey picture ({where}): the float is known by its orange and "
                                        "blue, give the camera's colour frames")
    return np.ascontiguousarray(image)


def replay(frames: list[tuple[int, float, Path, int]], H: np.ndarray, csv_path: str, *,
           lost_after_s: float = 4.0, size: tuple[int, int] | None = None) -> list[dict]:
    """One entry a frame; ``size``: TOWER.json's image_size, which every frame must have."""
    from vision.float_track import FloatTracker, track_frame
    tracker = FloatTracker(lost_after_s=lost_after_s)
    out = []
    for frame, t, path, lineno in frames:
        where = f"{csv_path} line {lineno}"
        image = read_image(path, where)
        if size is not None and tuple(image.shape[1::-1]) != tuple(size):
            raise BadInput(str(path), None, f"{image.shape[1]}x{image.shape[0]}, but TOWER.json was fitted to "
                                            f"{size[0]}x{size[1]} frames ({where}): its positions would be metres off")
        track, fix = track_frame(tracker, t, image, H)
        out.append({"t_s": t, "x_m": track.x_m, "y_m": track.y_m, "heading_rad": track.heading_rad,
                    "state": track.state, "frame": frame, "std_m": track.std_m, "speed_m_s": track.speed_m_s,
                    "confidence": None if fix is None else fix.confidence})
    return out


@click.command("track")
@click.option("--frames", "frames_dir", required=True, metavar="DIR",
              help="tower camera frames: DIR/frames.csv (frame,t_s,file) and the images it names")
@click.option("--tower", "tower_path", required=True, metavar="TOWER.json", help="pixel -> pond homography")
@click.option("--json", "json_path", required=True, metavar="OUT.json", help="the float's track, one entry a frame")
@click.option("--lost-after", "lost_after_s", default=4.0, show_default=True,
              type=Finite(min=0, min_open=True), metavar="S",
              help="seconds without a fix before the float is reported lost")
def track(frames_dir: str, tower_path: str, json_path: str, lost_after_s: float) -> None:
    """Replay tower camera frames through float detection and tracking; write the track."""
    import cv2
    cv2.setNumThreads(1)
    from controller.cli.output_paths import check_outputs
    H, size = load_tower_file(tower_path)
    frames = read_frames(frames_dir)
    check_outputs({"--json": json_path}, [tower_path, Path(frames_dir) / "frames.csv", *(f[2] for f in frames)])
    entries = replay(frames, H, str(Path(frames_dir) / "frames.csv"), lost_after_s=lost_after_s, size=size)
    from controller.atomic_files import write_text_atomically
    write_text_atomically(json_path, json.dumps({"track": entries}, indent=1) + "\n")
    states = [e["state"] for e in entries]
    click.echo(f"{len(entries)} frames: tracking {states.count('tracking')}, predicted {states.count('predicted')}, "
               f"lost {states.count('lost')}; written: {json_path}", err=json_path == "-")
