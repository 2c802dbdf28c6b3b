"""OpenCV FileStorage calibration files (YAML, XML, JSON from ``stereoCalibrate``) for
``fishfarm calibrate import``: which names mean which CALIB.json field, and the matrices under them.
Faults are BadInput naming the file and the key."""
from __future__ import annotations

import json
import re

import numpy as np

from controller.errors import BadInput
from vision.calib_file import has_bool

RECTIFIED = {"q", "r1", "r2"}              # stereoRectify's outputs (keys as name_key() gives them)
# The words tools use for a camera matrix and its distortion (OpenCV's stereoCalibrate and samples,
# ROS, MATLAB exports, hand-written files), each with the camera's tag after it (K1, camera_matrix_left,
# distCoeffsL) or "left"/"right" before it (left_camera_matrix). One list for K and D alike: a
# camera matrix found under a name whose distortion was not found lost D silently.
_K_WORDS = ("K", "M", "cameraMatrix", "camera_matrix", "mtx", "intrinsics", "intrinsic_matrix")
_D_WORDS = ("D", "distCoeffs", "dist_coeffs", "distortion", "distortion_coefficients", "dist",
            "distCoeff", "distortion_coeffs")
_TAGS = {1: ("1", "L", "left"), 2: ("2", "R", "right")}
_TAGS_FROM_0 = {1: ("0",), 2: ("1",)}       # camera_matrix_0 / _1: cameras counted from 0


def _camera_names(words: tuple[str, ...], tags: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(w + t for t in tags for w in words) + tuple(side + w for side in tags if len(side) > 2
                                                             for w in words)


def field_names(from_zero: bool = False) -> dict[str, tuple[str, ...]]:
    """CALIB.json field -> names other tools give it (compared as name_key gives them)."""
    tags = _TAGS_FROM_0 if from_zero else _TAGS
    return {
        "K1": _camera_names(_K_WORDS, tags[1]), "D1": _camera_names(_D_WORDS, tags[1]),
        "K2": _camera_names(_K_WORDS, tags[2]), "D2": _camera_names(_D_WORDS, tags[2]),
        "R": ("R", "rotation", "R_stereo", "stereo_R"),
        "T": ("T", "translation", "T_stereo", "stereo_T"),
        "image_size": ("imageSize", "image_size", "img_size", "size"),
        "image_width": ("image_width", "imageWidth", "width"),
        "image_height": ("image_height", "imageHeight", "height"),
    }


OPENCV_NAMES = field_names()
# a key like these that no field took is distortion this import does not understand: refused, not dropped
_DISTORTION_LIKE = re.compile(r"dist(?!ance)|distortion")
_NOT_COEFFICIENTS = re.compile(r"model|type")
# lens models other than OpenCV's pinhole + Brown-Conrady, as files name them (cv2.fisheye, ROS
# "equidistant", Kannala-Brandt, omnidirectional): their 4 coefficients are not k1 k2 p1 p2
_FISHEYE = re.compile(r"fish.?eye|equidistant|kannala|\bkb\d?\b|omni|double.?sphere|unified", re.I)


def name_key(name: str) -> str:
    return re.sub(r"[_\-]", "", name).lower()


class MatrixTypeError(ValueError):
    """A typed matrix whose written values its type cannot hold (FileStorage clips them: 1100 as 'u' is 255)."""


def node_array(node) -> np.ndarray | None:
    """A matrix node (!!opencv-matrix / type_id="opencv-matrix"), a list of numbers, a list of
    equally long lists of numbers (rows, as a JSON file written by hand has them) or a number."""
    if node.isSeq():
        items = [node.at(i) for i in range(node.size())]
        if all(i.isReal() or i.isInt() for i in items):
            return np.array([i.real() for i in items], dtype=float)
        rows = [node_array(i) if i.isSeq() else None for i in items]
        if not rows or any(r is None or r.ndim != 1 or len(r) != len(rows[0]) for r in rows):
            return None
        return np.array(rows)
    if node.isReal() or node.isInt():
        return np.array(node.real(), dtype=float)
    if node.isMap():
        if set(node.keys()) == {"rows", "cols", "data"}:      # ROS camera_info's matrices
            return _rows_cols(node)
        try:
            mat = node.mat()
        except Exception:         # cv2.error on a map that is not a matrix
            return None
        if mat is None:
            return None
        mat = np.asarray(mat, dtype=float)
        data = node.getNode("data")
        written = node_array(data) if data.isSeq() else None
        if written is not None and written.size == mat.size and not np.allclose(written.ravel(), mat.ravel(),
                                                                                rtol=1e-5, atol=0.0):
            raise MatrixTypeError(node.getNode("dt").string() or "?")
        return mat
    return None


def _rows_cols(node) -> np.ndarray | None:
    rows, cols, data = (node.getNode(k) for k in ("rows", "cols", "data"))
    values = node_array(data) if data.isSeq() else None
    if not (rows.isInt() and cols.isInt()) or values is None or values.ndim != 1:
        return None
    r, c = int(rows.real()), int(cols.real())
    return values.reshape(r, c) if r > 0 and c > 0 and r * c == values.size else None


def _open(path: str, text: str):
    import cv2

    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except Exception:         # cv2.error, or SystemError wrapping it, on a malformed file
        fs = None
    if fs is None or not fs.isOpened():
        _refuse_non_finite_json(path, text)
        raise BadInput(path, None, "not an OpenCV FileStorage file (YAML or XML)")
    root = fs.root()
    if not root.isMap():              # keys() asserts on an empty file or a list (exit 1 before)
        fs.release()
        raise BadInput(path, None, "holds no map of named matrices (K1, D1, K2, D2, R, T): it is empty, or its "
                                   "top level is a list or a value")
    twice = _nested_twice(text)
    if twice is not None:
        fs.release()
        raise BadInput(path, twice, "given twice: give it once")
    return fs


_YAML_KEY = re.compile(r"^( *)([A-Za-z_][\w.-]*)[ \t]*:")
_YAML_ITEM = re.compile(r"^( *)- +")


def _nested_twice(text: str) -> str | None:
    """A key given twice inside one of the file's maps (``M1.data``), which FileStorage reads as the
    first without a word (a matrix's ``data`` written twice, with other values: the first taken) and
    does not list either (its top level's are listed, and refused by ``_file_fields``). YAML by
    indentation, XML by element; JSON's are refused where it is parsed (``json_fields_once``)."""
    body = text.lstrip()
    if body.startswith("{"):
        return None
    if body.startswith("<"):
        return _xml_twice(body)
    stack: list[tuple[int, str, set[str]]] = [(-1, "", set())]      # (indent, key, its keys seen)
    for line in text.splitlines():
        item = _YAML_ITEM.match(line)
        if item is not None:          # a sequence's item: a map of its own (two cameras' K in a list)
            while stack[-1][0] >= len(item.group(1)):
                stack.pop()
            stack.append((len(item.group(1)), f"{stack[-1][1]}[]", set()))
            line = " " * len(item.group(0)) + line[len(item.group(0)):]
        m = _YAML_KEY.match(line)
        if m is None:
            continue
        indent, key = len(m.group(1)), m.group(2)
        while stack[-1][0] >= indent:
            stack.pop()
        parent = stack[-1]
        if key in parent[2] and indent > 0:
            return f"{parent[1]}.{key}"
        parent[2].add(key)
        stack.append((indent, f"{parent[1]}.{key}".lstrip("."), set()))
    return None


def _xml_twice(body: str) -> str | None:
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(body)
    except ET.ParseError:
        return None                   # (FileStorage read it: its own reading stands)

    def walk(node, name: str) -> str | None:
        tags = [c.tag for c in node if c.tag != "_"]       # "_": a sequence's items
        for tag in tags:
            if tags.count(tag) > 1:
                return f"{name}.{tag}"
        for child in node:
            hit = walk(child, f"{name}.{child.tag}".lstrip("."))
            if hit is not None:
                return hit
        return None
    for top in root:                  # (the top level's keys given twice: _file_fields names them)
        hit = walk(top, top.tag)
        if hit is not None:
            return hit
    return None


def _refuse_non_finite_json(path: str, text: str) -> None:
    """JSON that FileStorage cannot read because Python wrote NaN or Infinity into it: name the key."""
    found: list[str] = []

    def constant(word: str) -> float:
        found.append(word)
        return float("nan")
    try:
        doc = json.loads(text, parse_constant=constant)
    except (ValueError, RecursionError):
        return
    if found and isinstance(doc, dict):
        key = next((k for k, v in doc.items() if "nan" in json.dumps(v, allow_nan=True).lower()
                    or "infinity" in json.dumps(v, allow_nan=True).lower()), None)
        raise BadInput(path, key, f"{found[0]}: not a finite number (JSON has no NaN or Infinity)")


def refuse_fisheye(path: str, items) -> None:
    """(key, value) pairs: a string naming a fisheye model, or a key 'fisheye' set, is refused."""
    for key, value in items:
        said = value if isinstance(value, str) else ""
        flag = "fisheye" in name_key(key) and isinstance(value, (int, float)) and value != 0
        if _FISHEYE.search(said) or flag:
            raise BadInput(path, key, f"{value!r}: a fisheye (equidistant) lens model, which is not supported: "
                                      "only OpenCV's pinhole model (k1, k2, p1, p2[, k3 ...]) can be imported")


def _scalars(fs, keys) -> list:
    out = []
    for key in keys:
        node = fs.getNode(key)
        out.append((key, node.string() if node.isString() else node.real() if node.isReal() or node.isInt()
                    else None))
    return out


def _file_fields(path: str, fs) -> dict[str, tuple[str, np.ndarray]]:
    """CALIB field -> (key, array) in one file; two keys for one field refused."""
    listed = list(fs.root().keys())
    keyed = {name_key(k) for k in listed}
    from_zero = any(name_key(n) in keyed for n in field_names(True)["K1"])
    if from_zero and any(name_key(n) in keyed for n in field_names(False)["K2"]):
        zero = next(k for k in listed if name_key(k) in {name_key(n) for n in field_names(True)["K1"]})
        raise BadInput(path, zero, "beside the names of cameras 1 and 2: three cameras? give the pair as "
                                   "K1, K2 (or K0, K1), not all three")
    out = {}
    for field, names in field_names(from_zero).items():
        wanted = {name_key(n) for n in names}
        # every key of the field (image_size and imageSize are one name: the last one read won)
        hits = [k for k in listed if name_key(k) in wanted]
        distinct = list(dict.fromkeys(hits))
        if len(distinct) > 1:
            raise BadInput(path, f"{distinct[0]}, {distinct[1]}", f"two names for {field}: give it once")
        if len(hits) > 1:                           # FileStorage reads the first without a word
            raise BadInput(path, hits[0], "given twice: give it once")
        if hits:
            try:
                value = node_array(fs.getNode(hits[0]))
            except MatrixTypeError as exc:
                raise BadInput(path, hits[0], f"values its type dt '{exc}' cannot hold (OpenCV would clip or "
                                              "round them): write it as dt: d") from None
            if value is None:
                raise BadInput(path, hits[0], "not a matrix or a list of numbers")
            out[field] = hits[0], value
    return out


def _refuse_json_flags(path: str, text: str) -> None:
    """FileStorage reads JSON's true as 1 (a T of [true, 0, 0] was a 1 mm baseline) and keeps the
    first of a key given twice: both refused, by name."""
    from controller.cli.calib_io import json_fields_once
    try:
        doc = json_fields_once(path, text)
    except (ValueError, RecursionError):
        return                                  # FileStorage's reading names it
    for key, value in doc.items() if isinstance(doc, dict) else ():
        if has_bool(value.get("data") if isinstance(value, dict) else value):   # an "opencv-matrix" object's
            raise BadInput(path, key, "true/false where numbers are expected")


def _unknown_distortion(fs, taken: set[str]) -> list[str]:
    return [k for k in fs.root().keys() if k not in taken and _DISTORTION_LIKE.search(name_key(k))
            and not _NOT_COEFFICIENTS.search(name_key(k))]


def opencv_fields(files: list[tuple[str, str]]) -> tuple[dict, dict]:
    """CALIB field -> array from one or more FileStorage files (path, text: read once by the caller,
    unpacked if gzip'd); and which file gave each. A field in two files must have one value."""
    found, source, unknown = {}, {}, []
    for path, text in files:
        if text.lstrip().startswith("{"):
            _refuse_json_flags(path, text)
        fs = _open(path, text)
        try:
            refuse_fisheye(path, _scalars(fs, fs.root().keys()))
            fields = _file_fields(path, fs)
            unknown += [(path, k) for k in _unknown_distortion(fs, {k for k, _ in fields.values()})]
        finally:
            fs.release()
        for field, (key, value) in fields.items():
            if field in found and (found[field].shape != value.shape or not np.array_equal(found[field], value)):
                raise BadInput(path, key, f"also in {source[field]}, with other values: give {field} once")
            found.setdefault(field, value)
            source.setdefault(field, f"{path}: {key}")
    if unknown and {"K1", "K2"} <= set(found) and not {"D1", "D2"} <= set(found):
        path, key = unknown[0]
        raise BadInput(path, key, "looks like distortion, but is no name of D1 or D2 (D1, distCoeffs1, "
                                  "distortion_coefficients_left, ...): rename it, or drop it if it is not")
    return found, source


def opencv_size(found: dict, source: dict):
    if "image_size" in found:
        size = found["image_size"].reshape(-1)
        if size.size != 2:
            raise BadInput(source["image_size"], None, f"{size.size} values, expected [width, height]")
        other = _width_height(found, source)
        if other is not None and other != (float(size[0]), float(size[1])):
            raise BadInput(source["image_size"], None, f"{size[0]:g}x{size[1]:g}, but image_width and image_height "
                                                       f"say {other[0]:g}x{other[1]:g}: give the size once")
        return float(size[0]), float(size[1])          # whole pixels: vision.calib_import checks
    return _width_height(found, source)


def _width_height(found: dict, source: dict):
    if "image_width" in found or "image_height" in found:
        for given, missing in (("image_width", "image_height"), ("image_height", "image_width")):
            if missing not in found:
                raise BadInput(source[given].rsplit(": ", 1)[0], missing, f"missing: {given} is given without it")
        return float(found["image_width"].reshape(-1)[0]), float(found["image_height"].reshape(-1)[0])
    return None


def opencv_json(text: str | None) -> bool:
    """JSON as OpenCV's FileStorage writes it (its matrices typed "opencv-matrix"; any P1/P2 there
    are stereoRectify's), or a plain object naming K1/K2/R/T and no P1/P2."""
    try:
        doc = json.loads(text or "")
    except (ValueError, RecursionError):
        return False
    if not isinstance(doc, dict):
        return False
    if any(isinstance(v, dict) and v.get("type_id") == "opencv-matrix" for v in doc.values()):
        return True
    known = {name_key(n) for field in ("K1", "K2", "R", "T") for n in OPENCV_NAMES[field]}
    if not any(name_key(k) in known for k in doc):
        return False
    # P1/P2 beside stereoRectify's own products (Q, R1, R2) are rectified: the cameras are in K, D, R, T.
    # Without them, P1/P2 with K/R/T is CALIB.json's own form: the projections are the calibration
    return not {"P1", "P2"} & set(doc) or bool(RECTIFIED & {name_key(k) for k in doc})
