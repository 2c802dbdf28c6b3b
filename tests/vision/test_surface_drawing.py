"""Fish seen from above, drawn from the contract's words with cv2 primitives (independent of the
renderer): a spindle-shaped body widest about a third behind the snout, a narrow caudal peduncle,
a forked tail whose innermost notch point is the fork; on a tank floor under a lighting gradient,
with a bright lamp reflection and sensor noise. The tests of this file check the drawing itself."""
from __future__ import annotations

import cv2
import numpy as np

from devices.sim.stereo_rig import StereoRig, intrinsics, look_at


def outline(length: float, width_frac: float = 0.22, lobe: float = 0.17, n: int = 40) -> np.ndarray:
    """Fish outline (M, 2) in fish coordinates: x from the snout (0) to the fork notch (length),
    y lateral. The tail lobes reach past the fork to x = 1.15 length."""
    L = length
    x = np.linspace(0, 0.8 * L, n)
    half = 0.5 * width_frac * L * np.sin(np.pi * np.clip(x / (0.86 * L), 0, 1) ** 0.7)
    half = np.maximum(half, np.minimum(0.045 * L, x))
    top = np.c_[x, half]
    tail = np.array([[0.86 * L, 0.04 * L], [0.95 * L, 0.08 * L], [1.15 * L, lobe * L], [1.1 * L, 0.12 * L],
                     [L, 0.0], [1.1 * L, -0.12 * L], [1.15 * L, -lobe * L], [0.95 * L, -0.08 * L],
                     [0.86 * L, -0.04 * L]])
    return np.vstack([top, tail, top[::-1] * [1, -1]])


def edge_on(length: float, width_frac: float = 0.18, base: float = 0.87, tip: float = 1.12,
            n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A fish seen from above with its caudal fin standing edge-on, as fish from above mostly are: the
    body's outline (M, 2) up to the fin base (x = ``base`` x length), and the fin as a thin line
    (2, 2) from the base to the lobe tips at ``tip`` x length; the fork (x = length) lies on it,
    unseen."""
    L = length
    x = np.linspace(0, base * L, n)
    half = 0.5 * width_frac * L * np.sin(np.pi * np.clip(x / (base * L * 1.05), 0, 1) ** 0.7)
    half = np.maximum(half, np.minimum(0.03 * L, x))
    top = np.c_[x, half]
    body = np.vstack([top, top[::-1] * [1, -1]])
    return body, np.array([[base * L, 0.0], [tip * L, 0.0]])


def place(shape: np.ndarray, snout: np.ndarray, heading: float) -> np.ndarray:
    """Fish coordinates to image pixels: snout at ``snout``, body pointing from the snout towards
    the tail at angle ``heading`` (radians, image axes)."""
    d = np.array([np.cos(heading), np.sin(heading)])
    n = np.array([-d[1], d[0]])
    return snout + shape[:, :1] * d + shape[:, 1:] * n


def floor(size=(1280, 960), rng=None, gradient=(200, 90), noise=3.0) -> np.ndarray:
    """A tank floor lit from one side: brightness falling from ``gradient[0]`` to ``gradient[1]``
    along a diagonal, plus Gaussian noise."""
    w, h = size
    u, v = np.meshgrid(np.linspace(0, 1, w), np.linspace(0, 1, h))
    img = gradient[0] + (gradient[1] - gradient[0]) * (0.7 * u + 0.3 * v)
    if rng is not None:
        img = img + rng.normal(0, noise, img.shape)
    return np.clip(img, 0, 255).astype(np.float32)


def draw(img: np.ndarray, poly: np.ndarray, darkness: float = 0.45) -> None:
    """Fill a fish polygon (float px) darker than the floor under it, anti-aliased (in place)."""
    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.fillPoly(mask, [np.round(poly * 16).astype(np.int32)], 255, cv2.LINE_AA, shift=4)
    img *= 1 - darkness * mask.astype(np.float32) / 255


def reflection(img: np.ndarray, centre, axes, angle=20.0) -> None:
    """A lamp's reflection on the water: a saturated ellipse with a soft rim (in place)."""
    m = np.zeros(img.shape[:2], np.float32)
    cv2.ellipse(m, (int(centre[0]), int(centre[1])), (int(axes[0]), int(axes[1])), angle, 0, 360, 1.0, -1)
    m = cv2.GaussianBlur(m, (0, 0), 3)
    img += (255 - img) * m


def finish(img: np.ndarray, blur: float = 0.8) -> np.ndarray:
    return np.clip(cv2.GaussianBlur(img, (0, 0), blur), 0, 255).astype(np.uint8)


def top_rig(height_mm: float = 1000.0, baseline_mm: float = 200.0, focal_px: float = 1300.0,
            size=(1280, 960)) -> StereoRig:
    """Two cameras ``height_mm`` above the water (world z up, surface z = 0) looking down, side by
    side along x, converging on the tank floor point under them."""
    K = intrinsics(focal_px, size)
    target = np.array([0.0, 0.0, -100.0])
    cams = [look_at(np.array([sx * baseline_mm / 2, 0.0, height_mm]), target, np.array([0.0, 1.0, 0.0]))
            for sx in (-1, 1)]
    return StereoRig(K1=K, K2=K.copy(), R1=cams[0][0], t1=cams[0][1], R2=cams[1][0], t2=cams[1][1],
                     image_size=size, target=target)


def world_fish(length_mm: float, snout_xy, heading: float, depth_mm: float, tilt_deg: float = 0.0,
               **shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A fish's outline in world mm (M, 3) (flat, in a plane through its axis, tilted ``tilt_deg``
    nose-up), and its snout and fork points (3,)."""
    o = outline(length_mm, **shape)
    d = np.array([np.cos(heading), np.sin(heading)])
    c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
    snout = np.array([snout_xy[0], snout_xy[1], -depth_mm])
    along = np.r_[d * c, -s]              # from the snout towards the tail: down when nose-up
    lateral = np.r_[-d[1], d[0], 0.0]
    pts = snout + o[:, :1] * along + o[:, 1:] * lateral
    return pts, snout, snout + length_mm * along


def stereo_tank(rng: np.random.Generator, fish: list[dict], rig: StereoRig | None = None, glare=None):
    """A pair of a tank seen from above holding ``fish`` (kwargs of ``world_fish``), with a lamp
    reflection at ``glare`` ((u, v), (a, b)) in the left image. Returns left, right, rig, truths
    [(snout_mm, fork_mm, snout_px (2, 2), fork_px (2, 2))]."""
    rig = rig or top_rig()
    imgs = [floor(rig.image_size, rng), floor(rig.image_size, rng, gradient=(190, 95))]
    truths = []
    for f in fish:
        pts, s, k = world_fish(**{key: v for key, v in f.items() if key != "darkness"})
        for img, poly in zip(imgs, rig.project(pts), strict=False):
            draw(img, poly, darkness=f.get("darkness", 0.45))
        ps, pk = rig.project(np.vstack([s, k]))
        truths.append((s, k, np.array([ps[0], pk[0]]), np.array([ps[1], pk[1]])))
    if glare is not None:
        reflection(imgs[0], *glare)
    return finish(imgs[0]), finish(imgs[1]), rig, truths


def test_outline_fork_is_the_innermost_notch_point():
    o = outline(100.0)
    tail = o[o[:, 0] > 0.9 * 100]
    assert np.isclose(tail[:, 0].min(), 90.0) or tail[:, 0].min() > 90.0
    notch = o[np.argmin(np.abs(o[:, 1]) + (o[:, 0] < 50) * 1e9)]
    assert np.allclose(notch, [100.0, 0.0])
    assert o[:, 0].max() > 110.0                   # lobes reach past the fork


def test_stereo_tank_truth_projects_onto_the_drawn_fish():
    rng = np.random.default_rng(0)
    left, right, rig, truths = stereo_tank(rng, [dict(length_mm=120, snout_xy=(-50, 0), heading=0.3, depth_mm=150)])
    (s, k, pl, pr), = truths
    for img, px in ((left, pl), (right, pr)):
        mid = np.round((px[0] + px[1]) / 2).astype(int)
        assert img[mid[1], mid[0]] < img[mid[1], mid[0] + 200] - 30     # the body is darker than the floor
