"""Rigid transforms: inverse, relative poses, TUM rows, rotation angles, adjoints, SO(3) exp/log."""

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from vio_core import (
    ShapeError,
    adjoint,
    adjoints,
    check_transform,
    invert_transform,
    invert_transforms,
    make_transform,
    relative_transform,
    rotation_angle_deg,
    skew,
    skews,
    so3_exp,
    so3_log,
    transform_from_tum,
    transform_points,
    transform_to_tum,
)


def _random_pose(rng):
    return make_transform(Rotation.random(random_state=rng.integers(1 << 30)).as_matrix(), rng.normal(size=3))


def test_inverse_and_relative_transforms():
    rng = np.random.default_rng(0)
    T_w_a, T_w_b = _random_pose(rng), _random_pose(rng)
    np.testing.assert_allclose(invert_transform(T_w_a) @ T_w_a, np.eye(4), atol=1e-12)
    T_a_b = relative_transform(T_w_a, T_w_b)
    np.testing.assert_allclose(T_w_a @ T_a_b, T_w_b, atol=1e-12)
    p_b = rng.normal(size=(5, 3))
    np.testing.assert_allclose(transform_points(T_w_a, transform_points(T_a_b, p_b)),
                               transform_points(T_w_b, p_b), atol=1e-12)


def test_tum_row_round_trip_and_quaternion_check():
    rng = np.random.default_rng(1)
    T = _random_pose(rng)
    np.testing.assert_allclose(transform_from_tum(transform_to_tum(T)), T, atol=1e-12)
    row = transform_to_tum(T)
    row[3:] *= 1.5  # not a unit quaternion
    with pytest.raises(ValueError, match="quaternion norm"):
        transform_from_tum(row)


def test_rotation_angle_and_skew():
    R = Rotation.from_rotvec([0.0, 0.0, np.radians(30.0)]).as_matrix()
    assert rotation_angle_deg(R) == pytest.approx(30.0)
    assert rotation_angle_deg(np.eye(3)) == 0.0
    v, w = np.array([1.0, 2.0, 3.0]), np.array([-2.0, 0.5, 4.0])
    np.testing.assert_allclose(skew(v) @ w, np.cross(v, w))


def test_invalid_transforms_are_refused():
    T = np.eye(4)
    T[3, 0] = 1.0
    with pytest.raises(ShapeError, match="last row"):
        check_transform("T", T)
    T = np.eye(4)
    T[0, 0] = -1.0  # a reflection
    with pytest.raises(ShapeError, match="rotation"):
        check_transform("T", T)
    with pytest.raises(ShapeError, match="R"):
        make_transform(np.eye(2), np.zeros(3))


def test_adjoint_maps_right_perturbations():
    rng = np.random.default_rng(3)
    A = make_transform(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3))
    T = make_transform(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3))
    xi = rng.normal(scale=1e-4, size=6)

    def hat(x):
        M = np.zeros((4, 4))
        M[:3, :3] = [[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]]
        M[:3, 3] = x[3:]
        return M

    lhs = A @ T @ expm(hat(xi)) @ invert_transform(A)
    rhs = A @ T @ invert_transform(A) @ expm(hat(adjoint(A) @ xi))
    np.testing.assert_allclose(lhs, rhs, atol=1e-10)


def test_stacked_inverses_and_adjoints_match_the_single_ones():
    rng = np.random.default_rng(4)
    T = np.stack([_random_pose(rng) for _ in range(5)])
    inv, adj = invert_transforms(T), adjoints(T)
    assert inv.shape == (5, 4, 4) and adj.shape == (5, 6, 6)
    for k in range(5):
        np.testing.assert_allclose(inv[k], invert_transform(T[k]), atol=1e-12)
        np.testing.assert_allclose(adj[k], adjoint(T[k]), atol=1e-12)
    assert invert_transforms(np.zeros((0, 4, 4))).shape == (0, 4, 4)
    with pytest.raises(ShapeError):
        adjoints(T[0])  # one (4, 4) transform is not a stack


def _rotation_vectors(rng, n=200):
    """(n + 8, 3) rotation vectors: random angles up to pi, tiny ones, zero, pi and just under it."""
    axes = rng.normal(size=(n + 8, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.r_[rng.uniform(0, np.pi, n), 0.0, 1e-9, 1e-7, 2e-6, 1e-3, np.pi - 2e-3, np.pi - 1e-5, np.pi]
    return axes * angles[:, None]


def test_so3_exp_and_log_match_scipy_from_zero_to_pi():
    phi = _rotation_vectors(np.random.default_rng(3))
    R = so3_exp(phi)
    assert R.shape == (len(phi), 3, 3)
    np.testing.assert_allclose(R, Rotation.from_rotvec(phi).as_matrix(), atol=1e-12)
    back = so3_log(R)
    # the same rotation (at exactly pi, phi and -phi are one rotation)
    np.testing.assert_allclose(so3_exp(back), R, atol=1e-10)
    below = np.linalg.norm(phi, axis=1) < np.pi - 1e-6
    np.testing.assert_allclose(back[below], phi[below], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(back, axis=1), np.linalg.norm(phi, axis=1), atol=1e-9)


def test_so3_exp_log_and_skews_keep_leading_axes():
    phi = _rotation_vectors(np.random.default_rng(4), 16)[:24].reshape(4, 6, 3)
    assert so3_exp(phi).shape == (4, 6, 3, 3) and so3_log(so3_exp(phi)).shape == (4, 6, 3)
    v = phi[1, 2]
    np.testing.assert_array_equal(skews(phi)[1, 2], skew(v))
    np.testing.assert_allclose(skews(phi) @ phi[..., None], 0.0, atol=1e-15)  # v x v = 0
