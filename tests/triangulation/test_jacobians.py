"""Closed-form projection Jacobians (triangulation.jacobians) against their matrix products and
central differences."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from triangulation.jacobians import image_pose_jacobian, normal_terms, point_jacobian, pose_jacobian, sandwich2
from vio_core.geometry import make_transform


def test_closed_form_jacobians_equal_their_matrix_products_and_finite_differences():
    rng = np.random.default_rng(3)
    p_c = rng.uniform([-2, -2, 1], [2, 2, 20], (50, 3))
    R_cw = Rotation.from_rotvec(rng.normal(0, 0.5, (50, 3))).as_matrix()
    fx, fy = 450.0, 430.0
    x, y, z = p_c.T
    Jp = np.zeros((50, 2, 3))
    Jp[:, 0, 0], Jp[:, 0, 2] = fx / z, -fx * x / z**2
    Jp[:, 1, 1], Jp[:, 1, 2] = fy / z, -fy * y / z**2
    np.testing.assert_allclose(point_jacobian(p_c, fx, fy, R_cw), Jp @ R_cw, rtol=1e-12, atol=1e-9)
    J6 = image_pose_jacobian(p_c, fx, fy)
    np.testing.assert_allclose(J6, Jp @ pose_jacobian(p_c), rtol=1e-12, atol=1e-9)
    # the pixel motion under T_w_c * Exp(xi), by central differences, for one point
    T = make_transform(Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix(), [0.5, 0.1, -0.3])
    p_w = T[:3, :3] @ p_c[0] + T[:3, 3]

    def pixel(xi):
        Tp = T @ make_transform(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])
        q = Tp[:3, :3].T @ (p_w - Tp[:3, 3])
        return np.array([fx * q[0] / q[2], fy * q[1] / q[2]])

    h = 1e-6
    fd = np.column_stack([(pixel(h * e) - pixel(-h * e)) / (2 * h) for e in np.eye(6)])
    np.testing.assert_allclose(J6[0], fd, rtol=1e-5, atol=1e-5)
    A = rng.normal(size=(50, 6, 6))
    C = A @ np.transpose(A, (0, 2, 1))
    S = sandwich2(J6, C)
    np.testing.assert_allclose(S, J6 @ C @ np.transpose(J6, (0, 2, 1)), rtol=1e-12)
    assert np.array_equal(S[:, 0, 1], S[:, 1, 0])


def test_normal_terms_equal_their_matrix_products():
    rng = np.random.default_rng(4)
    J = rng.normal(size=(40, 2, 3))
    A = rng.normal(size=(40, 2, 2))
    S = A @ np.transpose(A, (0, 2, 1)) + np.eye(2)
    r = rng.normal(size=(40, 2))
    H, g, JtS = normal_terms(J, S, r)
    np.testing.assert_allclose(JtS, np.transpose(J, (0, 2, 1)) @ S, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(H, np.transpose(J, (0, 2, 1)) @ S @ J, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(g, np.einsum("nij,nj->ni", np.transpose(J, (0, 2, 1)) @ S, r), rtol=1e-12, atol=1e-12)
    assert normal_terms(J, S)[1] is None
