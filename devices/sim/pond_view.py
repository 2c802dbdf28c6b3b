"""The simulated tower camera's renderer: the pond seen from its tower, the float drawn through
the exact projection, and clips with ground truth on disk.

    scene, track = scenario("dropouts", seed=3, width=1920, height=1080, fps=30)
    frame = scene.render(t_s, FloatPose(x_m, y_m, heading_rad), occlusion=0.0)   # BGR uint8
    write_clip("clip/", scene, track)

A clip directory holds ``frames.csv`` (``frame,t_s,file``), one colour PNG per frame,
``truth.csv`` (``frame,t_s,x_m,y_m,heading_rad,visible``; visible = 1 when the float is in the
pond and less than half of it is hidden; x, y, heading empty with no float) and ``tower.json``
(``{"H": 3x3}`` pixel -> pond, plus ``image_size``).

    python -m devices.sim.pond_view SCENARIO --out DIR [--width W --height H --fps F --seed S --duration S]
                                   [--conditions JSON] [--tower=X,Y[,HEIGHT]] [--jpeg Q]
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from collections.abc import Iterable
from pathlib import Path

import cv2

from devices.sim.pond_camera import FloatPose, TowerView, tower_view
from devices.sim.pond_scenarios import SCENARIOS, scenario
from devices.sim.pond_scene import PondScene

__all__ = ["FloatPose", "PondScene", "TowerView", "scenario", "tower_view", "write_clip", "SCENARIOS"]
VISIBLE_BELOW = 0.5       # occlusion under which truth.csv calls the float visible


def write_clip(out_dir, scene: PondScene, track: Iterable[tuple[float, FloatPose | None, float]],
               fps_note: float | None = None, *, jpeg_quality: int | None = None) -> Path:
    """Render every (t_s, pose, occlusion) of ``track`` into ``out_dir``; returns the directory.
    ``fps_note`` (the nominal frame rate) is recorded in tower.json for people, never needed.
    ``jpeg_quality`` (1..100): each frame goes through JPEG first, as an IP camera's stream does
    (the PNG then holds the JPEG's artefacts)."""
    if jpeg_quality is not None and not 1 <= int(jpeg_quality) <= 100:
        raise ValueError(f"jpeg quality {jpeg_quality} is outside 1..100")
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    v = scene.view
    tower = {"H": v.H.tolist(), "image_size": [v.width, v.height]}
    if fps_note is not None:
        tower["fps"] = float(fps_note)
    (d / "tower.json").write_text(json.dumps(tower, indent=2) + "\n", encoding="utf-8")
    with open(d / "frames.csv", "w", newline="", encoding="utf-8") as ff, \
            open(d / "truth.csv", "w", newline="", encoding="utf-8") as tf:
        frames, truth = csv.writer(ff), csv.writer(tf)
        frames.writerow(["frame", "t_s", "file"])
        truth.writerow(["frame", "t_s", "x_m", "y_m", "heading_rad", "visible"])
        for i, (t_s, pose, occlusion) in enumerate(track):
            name = f"{i:06d}.png"
            img = scene.render(t_s, pose, occlusion=occlusion)
            if jpeg_quality is not None:
                ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
                if not ok:
                    raise OSError(f"frame {i}: JPEG encoding failed")
                img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
            if not cv2.imwrite(str(d / name), img, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
                raise OSError(f"{d / name}: could not write the frame")
            frames.writerow([i, repr(float(t_s)), name])
            if pose is None:
                truth.writerow([i, repr(float(t_s)), "", "", "", 0])
            else:
                truth.writerow([i, repr(float(t_s)), repr(float(pose.x_m)), repr(float(pose.y_m)),
                                repr(float(pose.heading_rad)), int(occlusion < VISIBLE_BELOW)])
    return d


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m devices.sim.pond_view",
                                description="Write a rendered tower-camera clip of the pond with ground truth.")
    p.add_argument("scenario", choices=sorted(SCENARIOS))
    p.add_argument("--out", required=True, help="directory for frames.csv, PNGs, truth.csv, tower.json")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=None, help="seconds (default: the scenario's)")
    p.add_argument("--conditions", default=None, help='JSON object overriding conditions, e.g. {"glare": 0.8}')
    p.add_argument("--tower", default=None, help="X,Y[,HEIGHT] of the tower camera, pond metres")
    p.add_argument("--jpeg", type=int, default=None, metavar="Q", help="pass frames through JPEG at quality Q")
    a = p.parse_args(argv)
    try:
        cond = json.loads(a.conditions) if a.conditions else None
        if cond is not None and not isinstance(cond, dict):
            raise ValueError("--conditions: not a JSON object")
        tower = [float(v) for v in a.tower.split(",")] if a.tower else []
        if a.tower and len(tower) not in (2, 3):
            raise ValueError("--tower: give X,Y or X,Y,HEIGHT")
        scene, track = scenario(a.scenario, seed=a.seed, width=a.width, height=a.height, fps=a.fps,
                                duration_s=a.duration, conditions=cond, tower_xy=tower[:2] or None,
                                tower_height_m=tower[2] if len(tower) == 3 else None)
        out = write_clip(a.out, scene, track, fps_note=a.fps, jpeg_quality=a.jpeg)
    except (ValueError, OSError) as e:
        print(f"pond_view: {e}", file=sys.stderr)
        return 2
    print(json.dumps({"out": str(out), "frames": len(track), "width": a.width, "height": a.height, "fps": a.fps}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
