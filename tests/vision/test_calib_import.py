"""Calibrations from other tools (vision/calib_import.py) and the frame-size check (calib_file).

Each case starts from a known rig, writes its calibration the way the other tool states it
(the DLT-11 relation with L12 = 1; OpenCV's x2 = R x1 + T; the tool's pixel convention), and
checks that triangulating the rig's pixels through the import gives back the world points.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from devices.sim.stereo_rig import StereoRig, convergent_rig, intrinsics, look_at
from vision.calib_file import CalibrationError, StereoCalibration, check_image_size, principal_point
from vision.calib_import import (
    UNITS_MM,
    dlt11_to_projection,
    from_calibration,
    from_dlt11,
    from_opencv,
    from_projections,
    pixel_transform,
)
from vision.triangulation import project, triangulate, triangulate_calibrated

RIG = convergent_rig()
WORLD = np.random.default_rng(4).uniform([0, 0, 0], [400, 400, 250], (50, 3))   # mm, in the rig's view


def _dlt11(P: np.ndarray) -> np.ndarray:
    """The 11 coefficients a DLT tool stores: P scaled so its last entry is 1, row by row."""
    return (P / P[2, 3]).reshape(-1)[:11]


def _camera1_frame(world: np.ndarray) -> np.ndarray:
    return world @ RIG.R1.T + RIG.t1


@pytest.mark.parametrize("units", ["mm", "cm", "m", "in"])
def test_dlt11_table_in_the_tools_unit_triangulates_in_mm(units):
    s = UNITS_MM[units]
    to_unit = np.diag([s, s, s, 1.0])                    # X_mm = s X_unit: P_unit = P_mm diag(s, s, s, 1)
    table = np.c_[_dlt11(RIG.P1 @ to_unit), _dlt11(RIG.P2 @ to_unit)]
    calib = from_dlt11(table, mm_per_unit=s)
    p1, p2 = RIG.project(WORLD)
    X, residual = triangulate(calib.P1, calib.P2, p1, p2)
    np.testing.assert_allclose(X, WORLD, atol=1e-6)
    assert residual.max() < 1e-6 and calib.image_size is None


def test_dlt11_relation_is_u_over_the_third_row_plus_one():
    L = np.arange(1.0, 12.0)
    P = dlt11_to_projection(L)
    x, y, z = 0.3, -0.7, 2.0
    w = L[8] * x + L[9] * y + L[10] * z + 1
    assert project(P, np.array([x, y, z]))[0] == pytest.approx(
        [(L[0] * x + L[1] * y + L[2] * z + L[3]) / w, (L[4] * x + L[5] * y + L[6] * z + L[7]) / w])
    with pytest.raises(CalibrationError, match="10 DLT coefficients"):
        dlt11_to_projection(L[:10])


@pytest.mark.parametrize("origin,y_up", [("one", False), ("corner", False), ("zero", True), ("one", True)])
def test_a_tools_pixel_convention_is_turned_into_opencvs(origin, y_up):
    """The tool's pixel of an OpenCV pixel (u, v): + 1 (1-based) or + 0.5 (from the corner), and
    v counted up from the bottom row; its P is that map applied to the rig's."""
    w, h = RIG.image_size
    d = {"zero": 0.0, "corner": 0.5, "one": 1.0}[origin]
    to_tool = np.array([[1.0, 0, d], [0, -1.0 if y_up else 1.0, (h - 1 + d) if y_up else d], [0, 0, 1.0]])
    calib = from_projections(to_tool @ RIG.P1, to_tool @ RIG.P2, pixel=pixel_transform(origin, y_up, h),
                             image_size=(w, h))
    for P, Q in ((calib.P1, RIG.P1), (calib.P2, RIG.P2)):
        np.testing.assert_allclose(project(P, WORLD), project(Q, WORLD), atol=1e-8)


def test_y_up_needs_the_height():
    with pytest.raises(CalibrationError) as err:
        pixel_transform("zero", y_up=True)
    assert err.value.field == "image_size"


@pytest.mark.parametrize("units", ["mm", "cm"])
def test_opencv_stereo_calibration_puts_the_world_in_camera_1s_frame(units):
    rig = convergent_rig(distortion=np.array([-0.12, 0.05, 0.001, -0.0005, 0.0]))
    R = rig.R2 @ rig.R1.T
    T = (rig.t2 - R @ rig.t1) / UNITS_MM[units]          # the board measured in ``units``
    calib = from_opencv(rig.K1, rig.D1.reshape(1, 5), rig.K2, rig.D2.reshape(5, 1), R, T.reshape(3, 1),
                        mm_per_unit=UNITS_MM[units], image_size=(1280, 960))
    np.testing.assert_allclose(calib.T, rig.t2 - R @ rig.t1, atol=1e-9)
    assert calib.has_distortion and calib.image_size == (1280, 960)
    p1, p2 = rig.project(WORLD)                          # distorted pixels
    X, _ = triangulate_calibrated(calib, p1, p2)
    np.testing.assert_allclose(X, WORLD @ rig.R1.T + rig.t1, atol=0.05)


@pytest.mark.parametrize("change,field", [
    ({"R": np.diag([1.0, 1.0, -1.0])}, "R"),               # a reflection
    ({"R": np.eye(3) * 2}, "R"),
    ({"K1": np.eye(3)[:2]}, "K1"),
    ({"K2": np.zeros((3, 3))}, "K2"),
    ({"T": np.zeros(3)}, "P2"),                             # no baseline
    ({"T": np.array([1.0, np.nan, 0.0])}, "T"),
    ({"D1": np.zeros(3)}, "D1"),
])
def test_opencv_faults_name_their_field(change, field):
    args = {"K1": RIG.K1, "D1": None, "K2": RIG.K2, "D2": None, "R": np.eye(3), "T": np.array([-400.0, 0, 0])}
    args.update(change)
    with pytest.raises(CalibrationError) as err:
        from_opencv(**args)
    assert err.value.field == field


def test_projection_faults_name_their_field():
    with pytest.raises(CalibrationError) as err:
        from_projections(RIG.P1, RIG.P1)
    assert err.value.field == "P2"                           # same centre: no baseline
    with pytest.raises(CalibrationError) as err:
        from_dlt11(np.ones((10, 2)))
    assert err.value.field == "coefficients"
    with pytest.raises(CalibrationError) as err:
        from_projections(RIG.P1, RIG.P2[:2])
    assert err.value.field == "P2"


# -- check_image_size ----------------------------------------------------------------------------

def _off_centre_rig() -> StereoRig:
    """A rig whose principal points are off-centre, cameras turned: P's decomposition is not trivial."""
    K = intrinsics(900.0, (800, 600))
    K[0, 2], K[1, 2] = 350.0, 320.0
    cams = [look_at(np.array([x, -900.0, 200.0]), np.zeros(3), np.array([0, 0, 1.0])) for x in (-150, 150)]
    return StereoRig(K1=K, K2=K.copy(), R1=cams[0][0], t1=cams[0][1], R2=cams[1][0], t2=cams[1][1],
                     image_size=(800, 600))


def test_principal_point_from_P_alone_is_Ks():
    rig = _off_centre_rig()
    only_p = StereoCalibration(P1=rig.P1 * -3.0, P2=rig.P2 * 0.01)     # any scale and sign
    for cam, P in ((1, rig.P1), (2, rig.P2)):
        K = cv2.decomposeProjectionMatrix(P)[0]
        np.testing.assert_allclose(principal_point(only_p, cam), K[:2, 2] / K[2, 2], atol=1e-6)
        np.testing.assert_allclose(principal_point(rig.calibration(), cam), [350.0, 320.0])


def test_image_size_must_be_the_frames():
    calib = RIG.calibration()
    check_image_size(calib, (1280, 960))
    for size in ((640, 480), (1920, 1080), (960, 1280)):
        with pytest.raises(CalibrationError) as err:
            check_image_size(calib, size)
        assert err.value.field == "image_size" and "1280x960" in str(err.value)


def test_without_image_size_the_principal_points_must_be_in_the_frames():
    rig = _off_centre_rig()
    calib = StereoCalibration(P1=rig.P1, P2=rig.P2)
    for size in ((800, 600), (1920, 1080), (351, 321)):
        check_image_size(calib, size)
    for size, field in (((350, 600), "P1"), ((800, 320), "P1"), ((320, 240), "P1")):
        with pytest.raises(CalibrationError) as err:
            check_image_size(calib, size)
        assert err.value.field == field and "principal point (350, 320)" in str(err.value)
    with_k = StereoCalibration(P1=rig.P1, P2=rig.P2, K1=rig.K1, K2=rig.K2)
    with pytest.raises(CalibrationError) as err:
        check_image_size(with_k, (300, 300))
    assert err.value.field == "K1"


@pytest.mark.parametrize("units", ["mm", "cm"])
def test_calib_json_s_own_form_keeps_every_field_and_scales_the_world(units):
    """P1, P2 and T from the world unit to mm; K, D, R, rms_px and other fields as they were."""
    s = UNITS_MM[units]
    R = RIG.R2 @ RIG.R1.T
    T = RIG.t2 - R @ RIG.t1
    to_unit = np.diag([s] * 3 + [1.0])
    D = [-0.1, 0.04, 0.0008, -0.0004, 0.0]
    data = {"P1": (RIG.K1 @ np.c_[np.eye(3), np.zeros(3)] @ to_unit).tolist(),
            "P2": (RIG.K2 @ np.c_[R, T] @ to_unit).tolist(), "K1": RIG.K1.tolist(), "D1": D,
            "K2": RIG.K2.tolist(), "D2": D, "R": R.tolist(), "T": (T / s).tolist(), "rms_px": 0.3, "pattern": [9, 6]}
    calib = from_calibration(data, mm_per_unit=s, extra={"method": "import"})
    np.testing.assert_allclose(calib.T, T)
    np.testing.assert_allclose(calib.D1, D)
    assert calib.rms_px == 0.3 and calib.extra == {"pattern": [9, 6], "method": "import"}
    X, _ = triangulate(calib.P1, calib.P2, *(project(P, WORLD) for P in (RIG.P1, RIG.P2)))
    np.testing.assert_allclose(X, _camera1_frame(WORLD), atol=1e-6)
    with pytest.raises(CalibrationError, match="without K1"):
        from_calibration({k: v for k, v in data.items() if k != "K1"})


@pytest.mark.parametrize("size, camera", [((600, 960), "K1"), ((1280, 400), "K1"), ((100, 100), "K1")])
def test_an_image_size_must_contain_both_principal_points(size, camera):
    """The check ran only without an image size: a size that cannot be the frames' was taken."""
    R = RIG.R2 @ RIG.R1.T
    with pytest.raises(CalibrationError) as err:
        from_opencv(RIG.K1, None, RIG.K2, None, R, RIG.t2 - R @ RIG.t1, image_size=size)
    assert err.value.field == "image_size" and camera in err.value.fault and f"{size[0]}x{size[1]}" in err.value.fault
    with pytest.raises(CalibrationError, match="P1"):                 # without K: P's principal point
        from_projections(RIG.P1, RIG.P2, image_size=size)
