"""OpenCV FileStorage calibration files (YAML, XML, JSON from ``stereoCalibrate``) for
``fishfarm calibrate import``: which names mean which CALIB.json field, and the matrices under them.
Faults are BadInput naming the file and the key."""
from __future__ import annotations

import json
import re

import numpy as np

from controller.errors import BadInput

RECTIFIED = {"q", "r1", "r2"}              # stereoRectify's outputs (keys as name_key() gives them)
# CALIB.json field -> names other tools give it (compared without case, "_" and "-")
OPENCV_NAMES = {
    "K1": ("K1", "M1", "cameraMatrix1", "camera_matrix1", "cameraMatrixL", "cameraMatrixLeft",
           "left_camera_matrix", "leftCameraMatrix", "mtxL", "mtx1", "KL", "K_left"),
    "D1": ("D1", "distCoeffs1", "dist_coeffs1", "distortion1", "distCoeffsL", "distCoeffsLeft",
           "left_distortion", "leftDistCoeffs", "distL", "dist1", "DL", "D_left"),
    "K2": ("K2", "M2", "cameraMatrix2", "camera_matrix2", "cameraMatrixR", "cameraMatrixRight",
           "right_camera_matrix", "rightCameraMatrix", "mtxR", "mtx2", "KR", "K_right"),
    "D2": ("D2", "distCoeffs2", "dist_coeffs2", "distortion2", "distCoeffsR", "distCoeffsRight",
           "right_distortion", "rightDistCoeffs", "distR", "dist2", "DR", "D_right"),
    "R": ("R", "rotation", "R_stereo", "stereo_R"),
    "T": ("T", "translation", "T_stereo", "stereo_T"),
    "image_size": ("imageSize", "image_size", "img_size", "size"),
    "image_width": ("image_width", "imageWidth", "width"),
    "image_height": ("image_height", "imageHeight", "height"),
}


def name_key(name: str) -> str:
    return re.sub(r"[_\-]", "", name).lower()


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
        try:
            mat = node.mat()
        except Exception:         # cv2.error on a map that is not a matrix
            return None
        return None if mat is None else np.asarray(mat, dtype=float)
    return None


def opencv_fields(files: list[tuple[str, str]]) -> tuple[dict, dict]:
    """CALIB field -> array from one or more FileStorage files (path, text: read once by the caller,
    unpacked if gzip'd); and which file gave each."""
    import cv2

    found, source = {}, {}
    for path, text in files:
        try:
            fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        except Exception:         # cv2.error, or SystemError wrapping it, on a malformed file
            fs = None
        if fs is None or not fs.isOpened():
            raise BadInput(path, None, "not an OpenCV FileStorage file (YAML or XML)")
        try:
            keys = {name_key(k): k for k in fs.root().keys()}
            for field, names in OPENCV_NAMES.items():
                key = next((keys[name_key(n)] for n in names if name_key(n) in keys), None)
                if key is None or field in found:
                    continue
                value = node_array(fs.getNode(key))
                if value is None:
                    raise BadInput(path, key, "not a matrix or a list of numbers")
                found[field], source[field] = value, f"{path}: {key}"
        finally:
            fs.release()
    return found, source


def opencv_size(found: dict, source: dict):
    if "image_size" in found:
        size = found["image_size"].reshape(-1)
        if size.size != 2:
            raise BadInput(source["image_size"], None, f"{size.size} values, expected [width, height]")
        return float(size[0]), float(size[1])          # whole pixels: vision.calib_import checks
    if "image_width" in found and "image_height" in found:
        return float(found["image_width"].reshape(-1)[0]), float(found["image_height"].reshape(-1)[0])
    return None


def opencv_json(text: str | None) -> bool:
    """JSON as OpenCV's FileStorage writes it (its matrices typed "opencv-matrix"; any P1/P2 there
    are stereoRectify's), or a plain object naming K1/K2/R/T and no P1/P2."""
    try:
        doc = json.loads(text or "")
    except ValueError:
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
