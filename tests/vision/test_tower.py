"""vision.tower: the tower camera's homography from surveyed points, and the sets it refuses."""
import numpy as np
import pytest

from vision.tower import TowerInputError, fit_tower, to_pond

POND = (20.0, 10.0)           # m, x along the length, y across
IMAGE = (1920, 1080)


def tower_camera(rng):
    """H pixel -> pond of a camera on a 6-10 m tower at the pond's edge, looking down at an angle."""
    centre = np.array([rng.uniform(5, 15), rng.uniform(-6, -3), rng.uniform(6, 10)])   # off the near side
    target = np.array([POND[0] / 2 + rng.uniform(-2, 2), POND[1] / 2 + rng.uniform(-1, 1), 0.0])
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])                    # world -> camera, rows are the camera's axes
    t = -R @ centre
    f = rng.uniform(900, 1300)
    K = np.array([[f, 0, IMAGE[0] / 2], [0, f, IMAGE[1] / 2], [0, 0, 1]])
    G = K @ np.c_[R[:, 0], R[:, 1], t]          # pond (x, y, 1) -> pixel
    H = np.linalg.inv(G)
    return H / H[2, 2], G


def project(G, pond):
    h = np.c_[pond, np.ones(len(pond))] @ G.T
    return h[:, :2] / h[:, 2:]


def pond_points(rng, n, G):
    pond = np.c_[rng.uniform(0, POND[0], 4 * n), rng.uniform(0, POND[1], 4 * n)]
    px = project(G, pond)
    inside = (px[:, 0] >= 0) & (px[:, 0] < IMAGE[0]) & (px[:, 1] >= 0) & (px[:, 1] < IMAGE[1])
    assert inside.sum() >= n
    return pond[inside][:n], px[inside][:n]


@pytest.mark.parametrize("seed", range(5))
def test_noisy_pixels_give_pond_positions_within_a_few_cm(seed):
    rng = np.random.default_rng(seed)
    H_true, G = tower_camera(rng)
    pond, px = pond_points(rng, 20, G)
    fit = fit_tower(px + rng.normal(0, 1.0, px.shape), pond)
    held_pond, held_px = pond_points(rng, 200, G)
    err = np.linalg.norm(to_pond(fit.H, held_px) - held_pond, axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.03 and err.max() < 0.08, err      # 1 px is ~2-4 cm far off
    assert 0 < fit.rms_m < 0.05 and fit.max_m >= fit.rms_m
    assert fit.H[2, 2] == 1.0


def test_exact_points_give_zero_residual_and_the_true_h():
    rng = np.random.default_rng(7)
    H_true, G = tower_camera(rng)
    pond, px = pond_points(rng, 4, G)
    fit = fit_tower(px, pond)
    assert fit.max_m < 1e-6
    np.testing.assert_allclose(fit.H, H_true, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(to_pond(fit.H, px), pond, atol=1e-6)


SQUARE_PX = np.array([[100.0, 100.0], [900.0, 120.0], [880.0, 700.0], [120.0, 680.0]])
SQUARE_M = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 10.0], [0.0, 10.0]])
LINE_PX = np.array([[100.0, 100.0], [300.0, 200.0], [500.0, 300.0], [700.0, 400.0], [900.0, 500.0]])
LINE_M = np.array([[0.0, 0.0], [5.0, 1.0], [10.0, 2.0], [15.0, 3.0], [20.0, 4.0]])
FIVE_PX = np.r_[SQUARE_PX, [[500.0, 400.0]]]
FIVE_M = np.r_[SQUARE_M, [[10.0, 5.0]]]


@pytest.mark.parametrize("px, pond, fault", [
    (SQUARE_PX[:3], SQUARE_M[:3], "3 points: at least 4"),
    (np.r_[SQUARE_PX[:3], [[np.nan, 5.0]]], SQUARE_M, "not a finite number"),
    (np.r_[SQUARE_PX[:3], [[np.inf, 5.0]]], SQUARE_M, "not a finite number"),
    (np.r_[FIVE_PX[:4], FIVE_PX[:1]], FIVE_M, "points 1 and 5 are the same in the image"),
    (FIVE_PX, np.r_[FIVE_M[:4], FIVE_M[2:3]], "points 3 and 5 are the same on the pond"),
    (LINE_PX, FIVE_M, "all 5 points lie on one line in the image"),
    (FIVE_PX, LINE_M, "all 5 points lie on one line on the pond"),
    (np.r_[SQUARE_PX[:2], [[500.0, 110.0]], SQUARE_PX[2:3]], SQUARE_M,
     "points 1, 2, 3 lie on one line in the image"),
    (SQUARE_PX, np.r_[SQUARE_M[:3], [[20.0, 5.0]]], "points 2, 3, 4 lie on one line on the pond"),
    (np.r_[LINE_PX[:4], [[400.0, 600.0]]], np.r_[LINE_M[:4], [[10.0, 8.0]]],
     "do not fix a homography"),
])
def test_degenerate_sets_are_refused_by_name(px, pond, fault):
    with pytest.raises(TowerInputError, match=fault):
        fit_tower(px, pond)


def test_nearly_collinear_noisy_line_is_refused():
    rng = np.random.default_rng(3)
    px = LINE_PX + rng.normal(0, 0.05, LINE_PX.shape)
    with pytest.raises(TowerInputError, match="one line in the image"):
        fit_tower(px, FIVE_M)


def test_mismatched_shapes_are_refused():
    with pytest.raises(TowerInputError, match="equal length"):
        fit_tower(SQUARE_PX, FIVE_M)


def test_to_pond_of_the_horizon_is_not_finite():
    H = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 1.0, -100.0]])
    assert not np.all(np.isfinite(to_pond(H, [[5.0, 100.0]])))


@pytest.mark.parametrize("seed", range(6))
def test_two_corners_swapped_on_the_pond_are_refused_as_no_camera_s_view(seed):
    """Four image corners whose pond positions two of are swapped fit a homography exactly (RMS 0),
    but one that folds the pond over: its horizon runs among the points. Refused, naming a point;
    the true four (and any 20 seen by a real tower camera) pass."""
    rng = np.random.default_rng(100 + seed)
    H_true, G = tower_camera(rng)
    corners_px = np.array([[200.0, 200.0], [1700.0, 200.0], [1700.0, 900.0], [200.0, 900.0]])
    corners_pond = to_pond(H_true, corners_px)
    assert fit_tower(corners_px, corners_pond).max_m < 1e-4
    for i, j in ((0, 1), (1, 2), (0, 3)):        # neighbours swapped: a bow tie
        swapped = corners_pond.copy()
        swapped[[i, j]] = swapped[[j, i]]
        with pytest.raises(TowerInputError, match=r"horizon runs among the points \(point \d lies beyond it\)"):
            fit_tower(corners_px, swapped)
    pond, px = pond_points(rng, 20, G)
    assert fit_tower(px, pond).max_m < 1e-6
