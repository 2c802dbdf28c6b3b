"""StereoMorph's own calibration file: what ``calibrateCameras`` writes (``calibration.txt``, R lists
in StereoMorph's XML4R text format), read for ``fishfarm calibrate import``.

Of its elements three are used: ``cal.coeff`` (the DLT-11 coefficients, one column per view),
``img.size`` (one row of width and height per view) and ``sq.size`` (the checkerboard square's
size with its unit, e.g. ``52.45 mm``: the unit of the DLT's world). A calibration made with
``undistort = TRUE`` (``undistort.params``) is refused: its coefficients apply to pixels undistorted
by StereoMorph's own lens model, which fishfarm does not have."""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from controller.errors import BadInput

_ELEMENT = re.compile(r"<([A-Za-z][\w.]*)((?:\s[^>]*)?)>(.*?)</\1\s*>", re.S)
_ATTRIBUTE = re.compile(r"([\w.]+)=(\S+)")


@dataclass(frozen=True)
class StereoMorphCalibration:
    coefficients: np.ndarray                # (11, 2): one column per view
    views: tuple[str, ...]
    image_size: tuple[int, int] | None
    units: str | None                       # the square size's unit (mm, cm, m, in), None if not given


def is_stereomorph_file(text: str | None) -> bool:
    head = (text or "").lstrip()
    return head.startswith("<calibration") or bool(re.search(r"<cal\.coeff[\s>]", head))


def _elements(text: str) -> dict[str, tuple[dict, str]]:
    """Top-level and nested elements by name (the first of each): (attributes, content)."""
    found: dict[str, tuple[dict, str]] = {}
    stack = [text]
    while stack:
        for m in _ELEMENT.finditer(stack.pop()):
            found.setdefault(m[1], (dict(_ATTRIBUTE.findall(m[2])), m[3]))
            if "<" in m[3]:
                stack.append(m[3])
    return found


def _matrix(path: str, name: str, attributes: dict, content: str) -> tuple[np.ndarray, list[str], list[str]]:
    """(values, column names, row names) of a ``type=matrix`` element."""
    lines = [line.split() for line in content.strip().splitlines() if line.strip()]
    cols = lines.pop(0) if attributes.get("colnames") == "TRUE" and lines else []
    rows: list[str] = []
    if attributes.get("rownames") == "TRUE":
        rows = [line.pop(0) for line in lines if line]
    try:
        values = np.array([[float(v) for v in line] for line in lines], dtype=float)
    except ValueError:
        raise BadInput(path, name, "not a matrix of numbers") from None
    if values.ndim != 2 or not np.isfinite(values).all():
        raise BadInput(path, name, "not a matrix of finite numbers, one row a line")
    nrow, ncol = attributes.get("nrow"), attributes.get("ncol")
    if (nrow and nrow.isdigit() and int(nrow) != values.shape[0]) or \
            (ncol and ncol.isdigit() and int(ncol) != values.shape[1]):
        raise BadInput(path, name, f"{values.shape[0]} x {values.shape[1]} values where the file says "
                                   f"nrow={nrow} ncol={ncol}")
    return values, cols, rows


def read_stereomorph(path: str, text: str, units_known: tuple[str, ...]) -> StereoMorphCalibration:
    elements = _elements(text)
    if "undistort.params" in elements:
        raise BadInput(path, "undistort.params", "made with StereoMorph's lens undistortion, whose model "
                                                 "fishfarm does not have: calibrate with undistort = FALSE")
    if "cal.coeff" not in elements:
        raise BadInput(path, "cal.coeff", "missing: not a finished StereoMorph calibration")
    coeff, views, _ = _matrix(path, "cal.coeff", *elements["cal.coeff"])
    if coeff.shape[0] != 11:
        raise BadInput(path, "cal.coeff", f"{coeff.shape[0]} rows: expected the 11 DLT coefficients")
    if coeff.shape[1] != 2:
        raise BadInput(path, "cal.coeff", f"{coeff.shape[1]} views ({', '.join(views) or 'unnamed'}): "
                                          "a stereo rig has 2; calibrate the pair on its own")
    return StereoMorphCalibration(coeff, tuple(views) or ("1", "2"), _image_size(path, elements),
                                  _units(path, elements, units_known))


def _image_size(path: str, elements: dict) -> tuple[int, int] | None:
    if "img.size" not in elements:
        return None
    sizes, _, views = _matrix(path, "img.size", *elements["img.size"])
    if sizes.shape[1] != 2 or len(sizes) < 1 or (sizes <= 0).any() or (sizes != np.round(sizes)).any():
        raise BadInput(path, "img.size", "expected a width and a height in pixels per view")
    if len({tuple(s) for s in sizes}) > 1:
        shown = ", ".join(f"{v or k + 1} {int(w)}x{int(h)}" for k, (v, (w, h)) in
                          enumerate(zip(views or [""] * len(sizes), sizes, strict=True)))
        raise BadInput(path, "img.size", f"the views differ ({shown}): a survey's pair has one size")
    return int(sizes[0, 0]), int(sizes[0, 1])


def _units(path: str, elements: dict, known: tuple[str, ...]) -> str | None:
    if "sq.size" not in elements:
        return None
    m = re.fullmatch(r"\s*[-+\d.eE]+\s*([A-Za-z]*)\s*", elements["sq.size"][1])
    if m is None:
        raise BadInput(path, "sq.size", f"{elements['sq.size'][1].strip()[:40]!r}: expected a size and its unit")
    if not m[1]:
        return None
    if m[1] not in known:
        raise BadInput(path, "sq.size", f"unit {m[1]!r} is not one of {', '.join(known)}: give --units")
    return m[1]
