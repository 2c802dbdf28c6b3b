"""Rendered survey scenes on disk, for benchmarks and for people outside the project.

A directory holds ``NNN_L.png`` / ``NNN_R.png`` (BGR, lossless), ``CALIB.json`` (the rig's exact
calibration, the project's CALIB format) and ``truth.jsonl``: one JSON object per pair with the
file names, the scene's drawn conditions and every fish's truth (world mm, pixels [[u1, v1],
[u2, v2]] left then right, fork length cm, weight g, flags).
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

TRUTH = "truth.jsonl"
CALIB = "CALIB.json"


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        return v.item()
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


def truth_record(scene, index: int) -> dict:
    """The JSON object ``write_scene`` appends for ``scene``."""
    fish = [{k: _plain(getattr(f, k)) for k in f.__dataclass_fields__} for f in scene.fish]
    return {"index": index, "left": f"{index:03d}_L.png", "right": f"{index:03d}_R.png",
            "image_size": list(scene.rig.image_size), "conditions": _plain(scene.conditions), "fish": fish}


def write_scene(scene, directory: str | Path, index: int) -> dict:
    """Write one pair, append its truth line, and write CALIB.json once; returns the record."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    rec = truth_record(scene, index)
    for name, img in ((rec["left"], scene.left), (rec["right"], scene.right)):
        if not cv2.imwrite(str(d / name), img):
            raise OSError(f"{d / name}: could not write the image")
    calib = d / CALIB
    if not calib.exists():
        calib.write_text(json.dumps(scene.rig.calibration().to_json(), indent=2) + "\n", encoding="utf-8")
    with open(d / TRUTH, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(rec) + "\n")
    return rec


def read_truth(directory: str | Path) -> list[dict]:
    """Every record of ``truth.jsonl`` in ``directory``, pixel and world arrays as numpy arrays."""
    out = []
    with open(Path(directory) / TRUTH, encoding="utf-8") as fh:
        for line in fh:
            rec = json.loads(line)
            for f in rec["fish"]:
                for k in ("snout_mm", "fork_mm", "snout_px", "fork_px"):
                    f[k] = np.asarray(f[k], float)
            out.append(rec)
    return out


def write_set(directory: str | Path, setup: str, count: int, seed: int,
              image_size: tuple[int, int] = (1280, 960), **conditions) -> list[dict]:
    """``count`` independent scenes (scene k drawn from seed ``seed`` + k) written to ``directory``;
    the rig's focal length scales with the image width (1400 px at 1280)."""
    from devices.sim.fish_scene import surface_rig, surface_scene, underwater_rig, underwater_scene
    make = {"underwater": underwater_scene, "surface": surface_scene}[setup]
    rig = {"underwater": underwater_rig, "surface": surface_rig}[setup](
        image_size=image_size, focal_px=1400.0 * image_size[0] / 1280)
    return [write_scene(make(np.random.default_rng(seed + k), rig=rig, **conditions), directory, k)
            for k in range(count)]


def main(argv: list[str] | None = None) -> int:
    import argparse
    ap = argparse.ArgumentParser(prog="python -m devices.sim.fish_io",
                                 description="Write rendered stereo survey scenes with truth.")
    ap.add_argument("out")
    ap.add_argument("--setup", choices=["underwater", "surface"], default="underwater")
    ap.add_argument("--count", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--species")
    ap.add_argument("--image-size", default="1280x960", help="WIDTHxHEIGHT")
    a = ap.parse_args(argv)
    try:
        size = tuple(int(v) for v in a.image_size.lower().split("x"))
        if len(size) != 2 or min(size) < 16:
            raise ValueError
    except ValueError:
        ap.error(f"--image-size: {a.image_size!r} is not WIDTHxHEIGHT")
    cond = {"species": a.species} if a.species else {}
    recs = write_set(a.out, a.setup, a.count, a.seed, image_size=size, **cond)
    print(json.dumps({"pairs": len(recs), "fish": sum(len(r["fish"]) for r in recs), "dir": str(a.out)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
