"""Where a survey's stereo pairs come from: image files (``--pair``, ``--rg``, ``--dir``) or video
(two synchronised files, or one RG video). Every source is an iterator of ``PairJob``: constant
memory whatever the length of the footage (a video is decoded one frame at a time).

Still images are named, not loaded, by their job (``paths``): the worker that measures the pair
reads it (``read_pair``), so reading runs on every core. Video is decoded in order by the parent
and the job carries the arrays. ``frame`` is the contract's: the pair's position among the
arguments, in sorted order with ``--dir``, or the frame number in the video (``--every N`` keeps
the original numbers: 0, N, 2N, ...).

Faults are ``BadInput`` naming the file: missing, unreadable or empty images, left and right of
different sizes or one picture twice, a directory without pairs. Video: controller/surveys/video_frames.py.
"""
from __future__ import annotations

import errno
import hashlib
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from controller.errors import BadInput
from controller.image_io import opencv_decode
from controller.surveys.frame_pixels import SAME_PICTURE, likeness, to_8bit
from controller.surveys.png import DamagedPNG, decode_png

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
BLUE_EMPTY_MAX = 16.0           # mean blue level an RG frame may carry (JPEG bleed, sensor offset)


@dataclass
class PairJob:
    frame: int
    where: str                              # names the input in messages
    paths: tuple[str, ...] = ()             # (left, right) files, or (rg,) one RG frame
    left: np.ndarray | None = None          # already decoded (video)
    right: np.ndarray | None = None
    read_s: float = 0.0                     # seconds the parent spent decoding it
    shared: tuple | None = None             # (file, offset, left shape, right shape): arrays in a shared map
    warning: str | None = None              # what decoding it noticed (an RG video's blue channel)


@dataclass
class Source:
    jobs: Iterator[PairJob]
    total: int | None                       # pairs to expect (progress bar), None when unknown
    fps: float | None = None                # video: frames are a sequence, fish are tracked
    warnings: list[str] | None = None
    every: int = 1                          # video: one frame surveyed in ``every``


# what OpenCV's codecs here read; the workers' frames travel as BMP (controller/surveys/wire.py)
IMAGE_KINDS = "PNG, JPEG, BMP or TIFF"


# ---- reading one pair ------------------------------------------------------------------------

def _imread(path: str, flags: int = cv2.IMREAD_ANYCOLOR) -> np.ndarray:
    p = Path(path)
    if not p.exists():
        raise BadInput(path, None, "no such file")
    if p.is_dir():
        raise BadInput(path, None, "is a directory, expected an image")
    if p.stat().st_size == 0:
        raise BadInput(path, None, "empty file")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise BadInput(path, None, f"cannot be read: {exc.strerror or exc}") from None
    return _imdecode(data, path, flags)


def _truncated(data: bytes) -> str | None:
    """Why an image file was cut short, or None. OpenCV decodes a JPEG cut in the middle of its
    scan as far as it goes (the rest grey) with only libjpeg's note on stderr, and a survey would
    measure that; a cut PNG fails with libpng's line on stderr beside ours."""
    if data[:2] == b"\xff\xd8":
        # in a scan 0xFF is always followed by 0x00 or a restart marker: FF D9 after the last
        # start of scan is the end of the image, wherever an EXIF thumbnail puts its own
        if data.find(b"\xff\xd9", max(data.rfind(b"\xff\xda"), 0)) < 0:
            return "truncated JPEG (no end-of-image marker after its last scan)"
    elif data[:8] == b"\x89PNG\r\n\x1a\n" and data.rfind(b"IEND") < 0:
        return "truncated PNG (no IEND chunk)"
    return None


def split_rg(img: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray, str | None]:
    """(left = red, right = green, warning or None) of an RG frame (BGR as OpenCV decodes it).

    A blue channel that is not empty is accepted with a warning: JPEG and some grabbers bleed
    into it, and refusing a whole survey for that helps no one; but a frame whose three channels
    are equal is a grey picture, not an RG frame, and left = right would measure nothing."""
    if img.ndim != 3 or img.shape[2] < 3:
        raise BadInput(where, None, "grey image: an RG frame is colour, left view in red, right in green")
    blue, green, red = img[..., 0], img[..., 1], img[..., 2]
    if np.array_equal(red, green) and np.array_equal(green, blue):
        raise BadInput(where, None, "red, green and blue are the same picture: not an RG frame")
    if (alike := likeness(red, green)) is not None and alike > SAME_PICTURE:
        raise BadInput(where, None, f"red and green are one picture (correlation {alike:.2f}; two cameras' "
                                    "views give under 0.2): not an RG frame of a stereo pair")
    level = float(cv2.mean(blue)[0])
    if level > BLUE_EMPTY_MAX:
        # a colour picture of one camera: its blue holds the scene as its red and green do (0.91-0.99
        # on rendered underwater views, where red against green fell to 0.80 and one camera's colour
        # video measured a fish at exit 0); an RG frame's blue is empty or bleed (0.21 at most, JPEG q75)
        for name, other in (("green", green), ("red", red)):
            if (alike := likeness(blue, other)) is not None and alike > SAME_PICTURE:
                raise BadInput(where, None, f"a colour picture, not an RG frame: its blue channel (mean level "
                                            f"{level:.0f}) is the picture its {name} is (correlation {alike:.2f})")
    warn = (f"{where}: blue channel not empty (mean level {level:.0f}): is this an RG frame? "
            "using red = left, green = right") if level > BLUE_EMPTY_MAX else None
    return np.ascontiguousarray(red), np.ascontiguousarray(green), warn


def check_two_views(left: np.ndarray, right: np.ndarray, left_name: str, right_name: str) -> None:
    """Two views of one pair: the same size, and not one picture twice (the same file or video given
    for both: its 'fish' are triangulated from a zero disparity into lengths that were never there).
    Two uniform frames alike (lights off, a capped lens) are a pair with nothing in it, not a fault."""
    check_same_dims(left.shape[1::-1], right.shape[1::-1], left_name, right_name)
    if np.array_equal(left, right) and left.size and not (left == left[0, 0]).all():
        raise BadInput(right_name, None, f"is the same picture as the left view {left_name}: "
                                         "a stereo pair is two cameras' views")
    # one picture twice, recompressed (a JPEG copy, the same clip in two containers): not equal, as
    # good as; its fish were invented from a zero disparity all the same
    if (alike := likeness(left, right)) is not None and alike > SAME_PICTURE:
        raise BadInput(right_name, None, f"is the left view {left_name} again (correlation {alike:.2f}; two "
                                         "cameras' views give under 0.2): a stereo pair is two cameras' views")


def check_two_files(left: str, right: str) -> None:
    """The same file given for both views, refused before anything is read."""
    try:
        same = os.path.samefile(left, right)
    except OSError:                 # one is missing: said where it is opened
        return
    if same:
        raise BadInput(right, None, f"is the same file as the left view {left}: a stereo pair is two "
                                    "cameras' views")


def check_same_dims(left: tuple[int, int], right: tuple[int, int], left_name: str, right_name: str) -> None:
    """Two views' (width, height) alike, else BadInput naming the right one."""
    if tuple(left) != tuple(right):
        (w1, h1), (w2, h2) = left, right
        raise BadInput(right_name, None, f"{w2}x{h2} pixels, but the left image {left_name} is {w1}x{h1}")


def _imdecode(data: bytes, name: str, flags: int = cv2.IMREAD_ANYCOLOR) -> np.ndarray:
    if not data:
        raise BadInput(name, None, "empty file")
    why = _truncated(data)
    if why:
        raise BadInput(name, None, why)
    try:
        img = decode_png(data, colour=flags == cv2.IMREAD_COLOR)
    except DamagedPNG as exc:
        raise BadInput(name, None, f"damaged PNG ({exc})") from None
    if img is None:      # at its own depth: 16-bit and float stills are made 8-bit by the pair (frame_pixels)
        img = opencv_decode(data, name, flags | cv2.IMREAD_ANYDEPTH, IMAGE_KINDS)
    if img is None or img.size == 0:
        raise BadInput(name, None, f"not a readable image ({IMAGE_KINDS} expected)")
    return img


def decode_pair(blobs: tuple[bytes, ...], names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, str | None]:
    """``read_pair`` of encoded files that travelled over the bus: (left, right) or one RG frame,
    decoded exactly as the files would be."""
    if len(blobs) == 1:
        return split_rg(to_8bit([_imdecode(blobs[0], names[0], cv2.IMREAD_COLOR)], [names[0]])[0], names[0])
    left, right = to_8bit([_imdecode(blobs[0], names[0]), _imdecode(blobs[1], names[1])], list(names))
    check_two_views(left, right, names[0], names[1])
    return left, right, None


def file_bytes(path: str) -> bytes:
    """A job's file as it lies on disk, for a worker to decode; the faults ``_imread`` names."""
    p = Path(path)
    if not p.exists():
        raise BadInput(path, None, "no such file")
    if p.is_dir():
        raise BadInput(path, None, "is a directory, expected an image")
    data = p.read_bytes()
    if not data:
        raise BadInput(path, None, "empty file")
    return data


def read_pair(job: PairJob) -> tuple[np.ndarray, np.ndarray, str | None]:
    """(left, right, warning) of a job, decoding its files if it names them."""
    if job.left is not None:
        return job.left, job.right, job.warning
    if len(job.paths) == 1:
        return split_rg(to_8bit([_imread(job.paths[0], cv2.IMREAD_COLOR)], [job.paths[0]])[0], job.paths[0])
    left, right = to_8bit([_imread(job.paths[0]), _imread(job.paths[1])], list(job.paths))
    check_two_views(left, right, job.paths[0], job.paths[1])
    return left, right, None


# ---- still images ----------------------------------------------------------------------------

def _exists(path: str) -> None:
    p = Path(path)
    if not p.exists():
        raise BadInput(path, None, "no such file")
    if p.is_dir():
        raise BadInput(path, None, "is a directory, expected an image")
    if not p.is_file():
        # a FIFO held the survey until something wrote to it, then was empty the second time it was
        # read; a <(...) was "no such file" to the worker processes that read stills
        raise BadInput(path, None, "not a regular file (a pipe, a socket or a device): a still is read as "
                                   "a file, more than once: save it to one first")


def _select(n: int, every: int, max_frames: int | None) -> list[int]:
    idx = list(range(0, n, every))
    return idx[:max_frames] if max_frames is not None else idx


def still_source(items: list[tuple[str, ...]], every: int = 1, max_frames: int | None = None) -> Source:
    """``items``: (left, right) pairs or (rg,) frames, in the order that defines ``frame``.
    Every file is checked to exist before any is measured (a typo fails at once, not at the end)."""
    for item in items:
        for path in item:
            _exists(path)
        if len(item) == 2:
            check_two_files(*item)
    kept, warnings = _distinct(items)
    chosen = [kept[k] for k in _select(len(kept), every, max_frames)]
    jobs = (PairJob(i, " + ".join(items[i]), paths=tuple(items[i])) for i in chosen)
    return Source(jobs, len(chosen), warnings=warnings)


def _distinct(items: list[tuple[str, ...]]) -> tuple[list[int], list[str]]:
    """(indices of the items whose images are not those of an earlier item, one warning per copy):
    a still copied under another name (or given twice) would count its fish twice over. Only files
    of equal sizes are read and hashed."""
    def size(path: str) -> int:
        try:
            return os.path.getsize(path)
        except OSError:
            return -1             # unreadable: the decoding says so, with its own words
    by_size: dict[tuple[int, ...], list[int]] = {}
    for i, item in enumerate(items):
        by_size.setdefault(tuple(size(p) for p in item), []).append(i)
    copies: dict[int, int] = {}
    for sizes, group in by_size.items():
        if len(group) < 2 or -1 in sizes:
            continue
        first: dict[tuple[str, ...], int] = {}
        for i in group:
            try:
                key = tuple(hashlib.sha256(file_bytes(p)).hexdigest() for p in items[i])
            except (BadInput, OSError):
                continue          # the decoding names the fault
            if key in first:
                copies[i] = first[key]
            else:
                first[key] = i
    warnings = [f"{' + '.join(items[i])}: the same images as {' + '.join(items[j])}: surveyed once"
                for i, j in sorted(copies.items())]
    return [i for i in range(len(items)) if i not in copies], warnings


_SIDE = re.compile(r"^(?P<stem>.*)_(?P<side>[LRlr])$")     # _l / _r too: a common naming


_SIDE_DIR = re.compile(r"^(?:.*[_\-. ])?(?P<side>l|r|left|right)$", re.IGNORECASE)


def directory_items(directory: str) -> list[tuple[str, ...]]:
    """``*_L.*`` / ``*_R.*`` pairs (``_l`` / ``_r`` too) in sorted order, or else every ``*.png`` as
    an RG frame; a directory without images, two folders of one view each (``*_L`` / ``*_R``,
    ``left`` / ``right``: StereoMorph's layout), their images paired by name."""
    d = Path(directory)
    if not d.exists():
        raise BadInput(directory, None, "no such directory")
    if not d.is_dir():
        raise BadInput(directory, None, "not a directory")
    files = _images(d)
    if not files:
        views = _view_folders(d)
        if views is not None:
            return _folder_pairs(*views)
    sides: dict[str, dict[str, Path]] = {}
    for p in files:
        m = _SIDE.match(p.stem)
        if m:
            side, got = m["side"].upper(), sides.setdefault(m["stem"], {})
            if side in got:         # a_L.png beside a_L.jpg or a_l.png: which one is meant is unknown
                raise BadInput(str(p), None, f"a second {'left' if side == 'L' else 'right'} image for "
                                             f"'{m['stem']}', beside {got[side].name}")
            got[side] = p
    if sides:
        lone = [p for p in files if not _SIDE.match(p.stem)]
        if lone:          # an RG frame or a stray image among pairs: left out, the count would rest on less
            raise BadInput(str(lone[0]), None, f"not one of a pair (*_L.* with *_R.*) beside {len(sides)} pairs"
                           + (f", nor are {len(lone) - 1} more" if len(lone) > 1 else "")
                           + ": move it out (RG frames are surveyed from a directory of their own)")
        items = []
        for stem in sorted(sides):
            got = sides[stem]
            for have, lack in (("L", "R"), ("R", "L")):
                if lack not in got:
                    _not_a_file(d, stem, lack)
                    raise BadInput(str(got[have]), None, f"no {'right' if lack == 'R' else 'left'} image "
                                                         f"({stem}_{lack}.*) beside it")
            items.append((str(got["L"]), str(got["R"])))
        return items
    rg = [(str(p),) for p in files if p.suffix.lower() == ".png"]
    if not rg:
        raise BadInput(directory, None, "no pairs (*_L.* with *_R.*, or folders *_L and *_R) and no *.png RG frames")
    return rg


def _not_a_file(d: Path, stem: str, side: str) -> None:
    """Name the view's image that is there but is no file to read (a folder, a dangling or looping
    link, a device): "no right image beside it" sent the user looking for a file they could see."""
    for p in sorted(d.iterdir()):
        m = _SIDE.match(p.stem)
        if m and m["stem"] == stem and m["side"].upper() == side and _named_as_image(p):
            what = ("a link that loops" if p.is_symlink() and _loops(p) else "a link to nothing" if not p.exists()
                    else "a directory" if p.is_dir() else "not a regular file")
            raise BadInput(str(p), None, f"{what}, not an image file")


def _loops(p: Path) -> bool:
    try:
        p.resolve(strict=True)
    except RuntimeError:                 # (Python < 3.13: a symlink loop)
        return True
    except OSError as exc:               # ELOOP
        return exc.errno == errno.ELOOP
    return False


def _images(d: Path) -> list[Path]:
    """The images in ``d``, sorted; hidden files are not (a Mac's ``._a_L.png`` AppleDouble beside
    every image copied from it aborted the survey as unreadable)."""
    return sorted(p for p in d.iterdir() if _named_as_image(p) and p.is_file())


def _named_as_image(p: Path) -> bool:
    """Named as an image a survey reads: an image suffix, not hidden."""
    return not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES


def _view_folders(d: Path) -> tuple[Path, Path] | None:
    """The left and right views' folders in ``d``; None when it holds none."""
    found: dict[str, Path] = {}
    for sub in sorted(p for p in d.iterdir() if p.is_dir() and not p.name.startswith(".")):
        m = _SIDE_DIR.match(sub.name)
        if m:
            side = m["side"][0].upper()
            if side in found:
                raise BadInput(str(sub), None, f"a second {'left' if side == 'L' else 'right'} view's folder, "
                                               f"beside {found[side].name}")
            found[side] = sub
    if len(found) == 1:
        [(side, only)] = found.items()
        raise BadInput(str(only), None, f"no {'right' if side == 'L' else 'left'} view's folder beside it")
    return (found["L"], found["R"]) if found else None


def _folder_pairs(left: Path, right: Path) -> list[tuple[str, ...]]:
    """The two views' images paired by name (``008428.jpeg`` in each), in sorted order."""
    views = []
    for folder in (left, right):
        named: dict[str, Path] = {}
        for p in _images(folder):
            if p.stem in named:
                raise BadInput(str(p), None, f"a second image for '{p.stem}', beside {named[p.stem].name}")
            named[p.stem] = p
        views.append(named)
    for (have, folder), other in (((views[0], right), views[1]), ((views[1], left), views[0])):
        lone = sorted(set(have) - set(other))
        if lone:
            raise BadInput(str(have[lone[0]]), None, f"no image named {lone[0]}.* in {folder} to pair it with"
                                                     + (f" ({len(lone) - 1} more alone)" if len(lone) > 1 else ""))
    if not views[0]:
        raise BadInput(str(left), None, "no images")
    return [(str(views[0][k]), str(views[1][k])) for k in sorted(views[0])]
