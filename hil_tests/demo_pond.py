"""The demo pond's tower camera, surveyed as on a farm: where the simulated tower camera sees known
points of the pond (its corners, the drain's corners, the feeder's foot, posts on the bank), and
the TOWER.json that `fishfarm calibrate tower` fits to them.

    python -m hil_tests.demo_pond [--config config/farm.toml]

writes the ``[cleaning] tower`` file's reference points (``tower_ref.csv`` beside it: ``u,v,x_m,y_m``)
and runs ``fishfarm calibrate tower`` on them. Run it again after a change of the pond, the tower
or the camera's size; tests/controller/test_demo_farm.py checks that the files agree with the
simulated camera. The HIL runs use ``tower_file`` for their own ponds (as ``python -m devices.sim.pond``
writes it: the camera's exact H, without a survey).
"""
from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PIXEL_DECIMALS = 3           # a survey's clicks, to a thousandth of a pixel


def sim_view(cfg):
    """The simulated tower camera of a validated config, built exactly as ``fishfarm sim`` builds it
    (devices/sim/world.py, devices/sim/pond.py)."""
    from devices.sections import validate_section
    from devices.sim.pond import pond_params, pond_view
    from devices.sim.tower_camera import SimTowerCameraParams
    sim = cfg.sim or {}
    camera = validate_section(SimTowerCameraParams, sim.get("tower_camera", {}), cfg.path, "sim.tower_camera")
    return pond_view(pond_params(cfg, sim.get("pond", {}), cfg.path), camera.width, camera.height, cfg.path)


def survey_points(outline, keepouts, bank_m: float = 0.3) -> np.ndarray:
    """(N, 2) pond points a surveyor would mark: the corners of the pond and of each keep-out (a
    round one's middle), and a post on the bank ``bank_m`` outside the middle of each side."""
    from shapely.geometry import Point, Polygon
    pond = Polygon(outline)
    points = [tuple(p) for p in outline]
    for k in keepouts:
        k = np.asarray(k, float)
        points += [tuple(p) for p in k] if len(k) <= 4 else [tuple(k.mean(axis=0))]
    ring = np.asarray(outline, float)
    for a, b in zip(ring, np.roll(ring, -1, axis=0), strict=True):
        mid, along = (a + b) / 2, b - a
        normal = np.array([along[1], -along[0]]) / np.hypot(*along)
        post = mid + bank_m * normal
        points.append(tuple(post if not pond.contains(Point(*post)) else mid - bank_m * normal))
    return np.array(points, float)


def reference_rows(view, points: np.ndarray) -> list[tuple[float, float, float, float]]:
    uv = np.round(view.to_pixels(points), PIXEL_DECIMALS)
    return [(float(u), float(v), float(x), float(y)) for (u, v), (x, y) in zip(uv, points, strict=True)]


def write_reference(path: Path, rows) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["u", "v", "x_m", "y_m"])
        for u, v, x, y in rows:
            w.writerow([f"{u:.{PIXEL_DECIMALS}f}", f"{v:.{PIXEL_DECIMALS}f}", f"{x:.4f}", f"{y:.4f}"])


def calibrate(ref: Path, out: Path, size: tuple[int, int] | None = None) -> str:
    """``fishfarm calibrate tower``, as an operator runs it (with the camera's frame size); its report."""
    sized = [] if size is None else ["--image-size", f"{size[0]}x{size[1]}"]
    done = subprocess.run([sys.executable, "-m", "controller.cli", "calibrate", "tower", "--points", str(ref),
                           "--out", str(out), *sized], cwd=ROOT, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"fishfarm calibrate tower failed: {done.stderr.strip()}")
    return done.stdout


def tower_file(view, out: Path) -> Path:
    """A TOWER.json of the camera ``view`` exactly (a HIL run's own pond)."""
    out.write_text(json.dumps({"H": view.H.tolist(), "image_size": [view.width, view.height]}) + "\n",
                   encoding="utf-8")
    return out


def main(argv=None) -> int:
    from controller.config import load_config
    ap = argparse.ArgumentParser(prog="python -m hil_tests.demo_pond", description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "config" / "farm.toml"))
    args = ap.parse_args(argv)
    cfg = load_config(args.config)
    if cfg.cleaning is None:
        print(f"{args.config}: no [cleaning] section", file=sys.stderr)
        return 2
    out = Path(cfg.cleaning.tower)
    out = out if out.is_absolute() else ROOT / out
    ref = out.with_name("tower_ref.csv")
    view = sim_view(cfg)
    rows = reference_rows(view, survey_points(cfg.cleaning.outline, cfg.cleaning.keepouts))
    write_reference(ref, rows)
    print(calibrate(ref, out, (view.width, view.height)), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
