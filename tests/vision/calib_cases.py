"""Bad CALIB.json contents and the one-line message each gives, as ``fishfarm`` gave them before the file
I/O moved out of vision/ (checked against that code once): the words the user reads must not change."""
import json
import re

import numpy as np

K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
P1 = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
P2 = K @ np.hstack([np.eye(3), [[-100.0], [0.0], [0.0]]])
GOOD = {"P1": P1.tolist(), "P2": P2.tolist()}
FULL = GOOD | {"K1": K.tolist(), "K2": K.tolist(), "D1": [-0.1, 0.05, 0.0, 0.0, 0.0]}


def _with(base, **changes):
    return json.dumps(base | changes)


SINGULAR = P2.copy()
SINGULAR[2, :3] = 0.0
K_ROW = K.copy()
K_ROW[2] = [0.0, 0.0, 2.0]

# (case, file text, the message after "FILE: ")
CASES = [
    ("not_an_object", "[1, 2]", "expected a JSON object with P1 and P2"),
    ("no_p1", json.dumps({"P2": GOOD["P2"]}), "P1: missing"),
    ("null_p2", _with(GOOD, P2=None), "P2: missing (null)"),
    ("text_matrix", _with(GOOD, P1=[["a", "b", "c", "d"]] * 3), "P1: not a numeric matrix"),
    ("p1_3x3", _with(GOOD, P1=K.tolist()), "P1: shape [3, 3], expected [3, 4]"),
    ("t_2", _with(GOOD, T=[1.0, 2.0]), "T: shape [2], expected [3]"),
    ("nan", _with(GOOD, R=[[float("nan")] * 3] * 3), "R: contains NaN or infinity"),
    ("d1_6", _with(FULL, D1=[0.0] * 6), "D1: 6 distortion coefficients (expected 4, 5, 8, 12 or 14)"),
    ("singular", _with(GOOD, P2=SINGULAR.tolist()), "P2: singular: its left 3x3 block has rank < 3"),
    ("one_centre", _with(GOOD, P1=P2.tolist(), P2=(3 * P2).tolist()),
     "P2: same camera centre as P1 ([100.0, 0.0, 0.0]): no baseline, nothing can be triangulated"),
    ("zero_k1", _with(FULL, K1=np.zeros((3, 3)).tolist()), "K1: singular: not an invertible camera matrix"),
    ("k1_last_row", _with(FULL, K1=K_ROW.tolist()), "K1: last row [0.0, 0.0, 2.0], expected [0, 0, 1]"),
    # an absurd K was taken (0.001 px: every triangulated point NaN) or called singular (1e12 px)
    ("k1_tiny_focal", _with(FULL, K1=[[0.001, 0, 320], [0, 0.001, 240], [0, 0, 1]]),
     "K1: focal lengths fx 0.001, fy 0.001 px: a camera's lie from 1 to 1e+07 px (is K in pixels?)"),
    ("k2_huge_focal", _with(FULL, K2=[[1e12, 0, 320], [0, 1e12, 240], [0, 0, 1]]),
     "K2: focal lengths fx 1e+12, fy 1e+12 px: a camera's lie from 1 to 1e+07 px (is K in pixels?)"),
    ("k1_far_centre", _with(FULL, K1=[[800, 0, 6.5e8], [0, 800, 240], [0, 0, 1]]),
     "K1: 6.5e+08 in its first rows: beyond 1e+07 px, no camera's (is K in pixels?)"),
    ("d2_without_k2", _with(GOOD, D2=[0.0] * 5), "D2: distortion given without K2"),
    ("image_size", _with(GOOD, image_size=[640]),
     "image_size: expected [width, height] in pixels (whole numbers 1..100000)"),
    ("image_size_flag", _with(GOOD, image_size=[True, 480]),
     "image_size: expected [width, height] in pixels (whole numbers 1..100000)"),
    ("image_size_half", _with(GOOD, image_size=[640.5, 480]),
     "image_size: expected [width, height] in pixels (whole numbers 1..100000)"),
    ("image_size_inf", _with(GOOD, image_size=[float("inf"), float("nan")]),
     "image_size: expected [width, height] in pixels (whole numbers 1..100000)"),
    ("image_size_huge", _with(GOOD, image_size=[10**30, 480]),
     "image_size: expected [width, height] in pixels (whole numbers 1..100000)"),
    ("rms", _with(GOOD, rms_px="small"), "rms_px: not a number"),
    ("not_json", "{P1: oops",
     "not valid JSON: Expecting property name enclosed in double quotes: line 1 column 2 (char 1)"),
]


def message_pattern(case: str, message: str) -> str:
    """The message as a regular expression; only a camera centre's zeros may carry a sign (SVD's)."""
    pattern = re.escape(message)
    if case == "one_centre":
        pattern = pattern.replace(r"0\.0", r"-?0\.0")
    return pattern
