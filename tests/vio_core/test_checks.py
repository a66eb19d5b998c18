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


def _check_transform_allclose(T) -> str:
    """The reference check_transform (np.allclose, np.linalg.det): '' or which error."""
    T = check_array("T", T, (4, 4), finite=True)
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        return "last row"
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
        return "rotation"
    return ""


def test_check_transform_matches_allclose_at_the_tolerances():
    """check_transform's scalar tests accept and reject exactly what np.allclose did: the
    last row and R @ R.T perturbed around their tolerances, reflections, float32, huge
    entries whose R @ R.T overflows."""
    rng = np.random.default_rng(7)
    R0 = Rotation.from_rotvec([0.3, -0.2, 0.1]).as_matrix()
    cases = []
    for scale in (1e-10, 1e-9, 1.00001e-5, 1e-5, 2e-5, 1e-3):
        for _ in range(20):
            T = make_transform(R0, rng.normal(size=3))
            T[3] += rng.choice([-1, 1], 4) * scale * rng.uniform(0.5, 1.5, 4)
            cases.append(T)
            T = make_transform(R0, rng.normal(size=3))
            T[:3, :3] += rng.normal(size=(3, 3)) * scale
            cases.append(T)
    for nudge in (0.0, 1e-9, 1e-5, 1.00001e-5 - 1e-9):  # at the boundary of the last row's 1
        T = make_transform(R0, [1, 2, 3])
        T[3, 3] += nudge
        T[3, 0] = nudge / 1e4
        cases.append(T)
    reflection = make_transform(R0, [0, 0, 0])
    reflection[:3, 0] *= -1.0
    huge = make_transform(R0, [0, 0, 0])
    huge[0, :3] = [1e200, -1e200, 1e200]
    cases += [reflection, huge, make_transform(R0, [1, 2, 3]).astype(np.float32)]
    outcomes = set()
    for T in cases:
        with np.errstate(over="ignore", invalid="ignore"):  # the huge case's R @ R.T
            want = _check_transform_allclose(T)
            outcomes.add(want)
            if want:
                with pytest.raises(ShapeError, match=want):
                    check_transform("T", T)
            else:
                assert check_transform("T", T) is T
    assert outcomes == {"", "last row", "rotation"}  # every path exercised


def test_check_transform_rejects_reflections_and_non_finite():
    T = make_transform(Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix(), [1, 2, 3])
    bad = T.copy()
    bad[:3, 2] *= -1.0  # orthonormal, determinant -1
    with pytest.raises(ShapeError, match="rotation"):
        check_transform("T", bad)
    bad = T.copy()
    bad[0, 3] = np.inf
    with pytest.raises(ShapeError, match="NaN or infinite"):
        check_transform("T", bad)
    with pytest.raises(ShapeError, match=r"T: expected shape \(4, 4\), got \(3, 4\)"):
        check_transform("T", T[:3])
    with pytest.raises(ShapeError, match=r"expected shape \(4, 4\), got \(4, 4, 1\)"):
        check_transform("T", T[..., None])
