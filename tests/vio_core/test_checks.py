import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError, ShapeError, VioDepthError
from vio_core.geometry import (
    invert_transform,
    make_transform,
    relative_transform,
    transform_from_tum,
    transform_points,
    transform_to_tum,
)


def test_check_array_shape_dtype_and_finite():
    assert check_array("p", np.zeros((4, 3)), (None, 3)).shape == (4, 3)
    assert check_array("p", np.zeros((4, 3), int), (None, 3)).dtype == np.float64
    with pytest.raises(ShapeError, match=r"p: expected shape \(N, 3\), got \(4, 2\)"):
        check_array("p", np.zeros((4, 2)), (None, 3))
    with pytest.raises(ShapeError, match="NaN"):
        check_array("p", np.array([[0.0, np.nan, 1.0]]), (None, 3), finite=True)
    with pytest.raises(ShapeError, match="integer"):
        check_array("i", np.zeros(3), (None,), dtype="int")
    assert issubclass(ShapeError, VioDepthError) and issubclass(ShapeError, ValueError)


def test_check_transform_rejects_non_rigid():
    T = make_transform(Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix(), [1, 2, 3])
    check_transform("T", T)
    bad = T.copy()
    bad[:3, :3] *= 2.0
    with pytest.raises(ShapeError, match="rotation"):
        check_transform("T", bad)
    bad = T.copy()
    bad[3, 0] = 1.0
    with pytest.raises(ShapeError, match="last row"):
        check_transform("T", bad)


def test_transforms_compose_invert_and_tum_round_trip():
    rng = np.random.default_rng(0)
    T_w_a = make_transform(Rotation.random(random_state=1).as_matrix(), rng.normal(size=3))
    T_w_b = make_transform(Rotation.random(random_state=2).as_matrix(), rng.normal(size=3))
    T_a_b = relative_transform(T_w_a, T_w_b)
    p_b = rng.normal(size=(5, 3))
    np.testing.assert_allclose(transform_points(T_w_a @ T_a_b, p_b), transform_points(T_w_b, p_b), atol=1e-12)
    np.testing.assert_allclose(invert_transform(T_a_b) @ T_a_b, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(transform_from_tum(transform_to_tum(T_w_a)), T_w_a, atol=1e-12)


def test_camera_project_backproject_and_distortion_round_trip():
    cam = Camera(640, 480, 500.0, 510.0, 320.0, 240.0, dist=(-0.2, 0.05, 0.001, -0.0005, 0.0))
    rng = np.random.default_rng(3)
    p = np.c_[rng.uniform(-2, 2, (50, 2)), rng.uniform(2, 10, 50)]
    uv, z = cam.project(p)
    np.testing.assert_allclose(cam.backproject(uv, z), p, atol=1e-9)
    inside = cam.in_image(uv, margin=40)
    raw = cam.distort_points(uv[inside])
    np.testing.assert_allclose(cam.undistort_points(raw), uv[inside], atol=1e-4)
    assert np.abs(raw - uv[inside]).max() > 1.0  # distortion is not a no-op
    uv_behind, _ = cam.project(np.array([[0.0, 0.0, -1.0]]))
    assert np.isnan(uv_behind).all()


def test_camera_rejects_bad_intrinsics():
    with pytest.raises(InputError):
        Camera(0, 480, 500, 500, 320, 240)
    with pytest.raises(InputError):
        Camera(640, 480, -1, 500, 320, 240)
    with pytest.raises(InputError):
        Camera(640, 480, 500, 500, 320, 240, dist=(0.1, 0.2, 0.3))


def test_lookup_returns_the_entry_or_lists_valid_names():
    from vio_core.errors import UnknownNameError, lookup

    table = {"b": 2, "a": 1}
    assert lookup("thing", "a", table) == 1
    with pytest.raises(UnknownNameError, match=r"unknown thing 'c'; valid names: a, b"):
        lookup("thing", "c", table)
    with pytest.raises(ValueError):  # unhashable names are unknown too, not a TypeError
        lookup("thing", ["a"], table)
