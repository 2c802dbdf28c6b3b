"""Textured planes seen by two pinhole cameras: stereo pairs with exact ground truth for matching.

A plane (a point and a normal, world mm) carries a texture of ``texel_mm`` square texels. Each
camera P (3, 4) sees it through the homography P . A, A mapping texel (col, row, 1) to the world
point; the image is the texture warped by it (bilinear, OpenCV pixel-centre convention), then lit
(gain, offset, a vertical fall-off like sunlight attenuating with depth), given Gaussian sensor
noise and quantised to 8 bits. The true match of a pixel of image 1 is H21 = H2 H1^-1 applied to it.

All randomness comes from the caller's ``numpy.random.Generator``.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def random_texture(shape: tuple[int, int], rng: np.random.Generator,
                   scales: tuple[float, ...] = (1.5, 4.0, 12.0)) -> np.ndarray:
    """Texture (rows, cols) float32 in [0, 1]: white noise blurred at several scales (texels) and
    summed, normalised to 1 %..99 % percentiles, like the mottled skin and water of a tank."""
    out = np.zeros(shape, np.float32)
    for sigma in scales:
        layer = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), sigma)
        out += layer / layer.std()
    lo, hi = np.percentile(out, [1, 99])
    return np.clip((out - lo) / (hi - lo), 0, 1)


def stripes(shape: tuple[int, int], period_texels: float, angle_rad: float = 0.0) -> np.ndarray:
    """Repetitive texture (rows, cols) in [0, 1]: sinusoidal stripes whose crests run across
    ``angle_rad`` (0: varying along the columns), the trap for any matcher along a line."""
    rows, cols = np.indices(shape, dtype=np.float32)
    phase = cols * np.cos(angle_rad) + rows * np.sin(angle_rad)
    return (0.5 + 0.5 * np.sin(2 * np.pi * phase / period_texels)).astype(np.float32)


def plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two orthonormal in-plane axes; the first as horizontal as possible (world z up)."""
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    e1 = np.cross([0.0, 0.0, 1.0], normal)
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross([1.0, 0.0, 0.0], normal)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(normal, e1)


@dataclass
class PlaneScene:
    img1: np.ndarray          # (H, W) uint8
    img2: np.ndarray
    H1: np.ndarray            # (3, 3) texel -> image 1 pixel
    H2: np.ndarray            # (3, 3) texel -> image 2 pixel
    texture_shape: tuple[int, int]

    @property
    def H21(self) -> np.ndarray:
        """Image 1 pixel -> image 2 pixel for points of the plane."""
        return self.H2 @ np.linalg.inv(self.H1)

    def truth(self, pts1: np.ndarray) -> np.ndarray:
        """True matches (N, 2) in image 2 of pixels (N, 2) of image 1."""
        return _apply(self.H21, pts1)

    def on_texture(self, pts1: np.ndarray, margin_texels: float = 20.0) -> np.ndarray:
        """(N,) bool: the pixel of image 1 sees the textured part of the plane, not its border."""
        t = _apply(np.linalg.inv(self.H1), pts1)
        rows, cols = self.texture_shape
        return ((t[:, 0] >= margin_texels) & (t[:, 0] <= cols - 1 - margin_texels)
                & (t[:, 1] >= margin_texels) & (t[:, 1] <= rows - 1 - margin_texels))


def _apply(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    pts = np.asarray(pts, float).reshape(-1, 2)
    x = np.c_[pts, np.ones(len(pts))] @ H.T
    return x[:, :2] / x[:, 2:]


def _light(img: np.ndarray, gain: float, offset: float, falloff: float, noise: float,
           rng: np.random.Generator) -> np.ndarray:
    """Grey levels: gain and offset, brightness falling by ``falloff`` (a fraction) from the top row
    to the bottom one, sensor noise (grey levels), 8-bit quantisation."""
    rows = img.shape[0]
    light = 1.0 - falloff * np.linspace(0.0, 1.0, rows, dtype=np.float32)[:, None]
    out = 255.0 * img * gain * light + offset
    if noise > 0:
        out = out + rng.normal(0.0, noise, img.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def textured_plane(P1: np.ndarray, P2: np.ndarray, image_size: tuple[int, int], point_mm: np.ndarray,
                   normal: np.ndarray, rng: np.random.Generator, *, texel_mm: float = 1.0,
                   texture: np.ndarray | None = None, texture_shape: tuple[int, int] = (1200, 1500),
                   gain: tuple[float, float] = (0.8, 0.8), offset: tuple[float, float] = (20.0, 20.0),
                   falloff: tuple[float, float] = (0.0, 0.0),
                   noise: tuple[float, float] = (1.0, 1.0), background: float | None = None) -> PlaneScene:
    """Render a textured plane through P1 and P2 (pixel <- world mm) into (W, H) = image_size images.

    The texture (default ``random_texture(texture_shape)``) is centred on ``point_mm``; its columns
    run along the plane's most horizontal axis. gain/offset/falloff/noise: per camera (1, 2).
    Beyond the texture the plane repeats it mirrored, or is uniform ``background`` (0..1) if given.
    """
    if texture is None:
        texture = random_texture(texture_shape, rng)
    rows, cols = texture.shape
    e1, e2 = plane_basis(normal)
    origin = np.asarray(point_mm, float) - texel_mm * ((cols - 1) / 2 * e1 + (rows - 1) / 2 * e2)
    A = np.vstack([np.c_[texel_mm * e1, texel_mm * e2, origin], [0.0, 0.0, 1.0]])   # texel -> world
    images, Hs = [], []
    for i, P in enumerate((P1, P2)):
        H = np.asarray(P, float) @ A
        Hs.append(H / H[2, 2])
        border = (dict(borderMode=cv2.BORDER_REFLECT) if background is None
                  else dict(borderMode=cv2.BORDER_CONSTANT, borderValue=float(background)))
        warped = cv2.warpPerspective(texture, Hs[-1], tuple(image_size), flags=cv2.INTER_LINEAR, **border)
        images.append(_light(warped, gain[i], offset[i], falloff[i], noise[i], rng))
    return PlaneScene(images[0], images[1], Hs[0], Hs[1], (rows, cols))


def chessboard_texture(pattern: tuple[int, int], texels_per_square: int = 32) -> np.ndarray:
    """A printed board with ``pattern`` = (cols, rows) inner corners and a one-square white margin,
    lightly blurred (print and lens are never perfectly sharp). Texture (rows, cols) in [0, 1]."""
    cols, rows = pattern[0] + 1, pattern[1] + 1
    r, c = np.indices((rows + 2, cols + 2))
    squares = ((r + c) % 2 == 0) & (r >= 1) & (r <= rows) & (c >= 1) & (c <= cols)
    board = np.where(squares, 0.05, 0.95).astype(np.float32)
    big = cv2.resize(board, None, fx=texels_per_square, fy=texels_per_square, interpolation=cv2.INTER_NEAREST)
    return cv2.GaussianBlur(big, (0, 0), 0.5 * texels_per_square / 16)


def chessboard_views(P1: np.ndarray, P2: np.ndarray, image_size: tuple[int, int],
                     pattern: tuple[int, int], square_mm: float, poses: list[tuple[np.ndarray, np.ndarray]],
                     rng: np.random.Generator, texels_per_square: int = 32,
                     noise: float = 1.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Image pairs (img1, img2) of a chessboard at each pose = (centre_mm, normal), world mm."""
    texture = chessboard_texture(pattern, texels_per_square)
    texel = square_mm / texels_per_square
    pairs = []
    for centre, normal in poses:
        scene = textured_plane(P1, P2, image_size, centre, normal, rng, texel_mm=texel, texture=texture,
                               gain=(0.9, 0.9), offset=(10.0, 10.0), noise=(noise, noise), background=0.95)
        pairs.append((scene.img1, scene.img2))
    return pairs


@dataclass
class BoardSession:
    """A calibration session: image pairs of a board at random poses, and the rig that took them."""

    pairs: list[tuple[np.ndarray, np.ndarray]]
    K: np.ndarray             # (3, 3) both cameras
    R: np.ndarray             # (3, 3) camera 2 <- camera 1
    T: np.ndarray             # (3,) mm, camera 2 <- camera 1
    image_size: tuple[int, int]


def board_session(n: int, rng: np.random.Generator, pattern: tuple[int, int] = (9, 6),
                  square_mm: float = 25.0) -> BoardSession:
    """``n`` pairs, 640x480, of a board ~0.5 m away, tilted up to ~35 degrees, seen by two cameras
    (f = 600 px) 80 mm apart, camera 2 on the right and toed in by 4 degrees."""
    K = np.array([[600.0, 0, 319.5], [0, 600, 239.5], [0, 0, 1]])
    a = np.radians(-4)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    T = -R @ np.array([80.0, 0, 0])
    poses = []
    for _ in range(n):
        centre = np.array([40.0, 0, 550]) + rng.uniform([-60, -40, -80], [60, 40, 80])
        tilt = rng.uniform(-0.6, 0.6, 2)
        poses.append((centre, np.array([np.sin(tilt[0]), np.sin(tilt[1]), -1.0])))
    P1, P2 = K @ np.c_[np.eye(3), np.zeros(3)], K @ np.c_[R, T]
    pairs = chessboard_views(P1, P2, (640, 480), pattern, square_mm, poses, rng)
    return BoardSession(pairs, K, R, T, (640, 480))
