"""refine_pose: one frame's pose against known landmarks, with a pose prior."""

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.geometry import invert_transform, make_transform
from vio_depth.landmarks.resection import _normal_equations, refine_pose

CAMERA = Camera.from_K(np.array([[450.0, 0, 376], [0, 450.0, 282], [0, 0, 1]]), 752, 564)


def _scene(rng, n=300):
    T_w_c = make_transform(Rotation.from_rotvec([0.02, -0.05, 0.01]).as_matrix(), [0.3, -0.1, 0.2])
    p_c = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2, 8, n)])
    points_w = p_c @ T_w_c[:3, :3].T + T_w_c[:3, 3]
    uv = p_c[:, :2] / p_c[:, 2:] * 450.0 + [376.0, 282.0]
    return T_w_c, points_w, uv


def test_recovers_the_pose_from_a_perturbed_prior():
    rng = np.random.default_rng(0)
    T_true, points_w, uv = _scene(rng)
    uv_noisy = uv + rng.normal(0, 0.3, uv.shape)
    uv_noisy[:10] += 40.0  # ten gross outliers: Huber keeps them from pulling the pose
    T_prior = T_true @ make_transform(Rotation.from_rotvec([0.01, 0.0, -0.01]).as_matrix(), [0.05, 0.02, -0.03])
    res = refine_pose(points_w, np.zeros((len(uv), 3, 3)), uv_noisy, CAMERA, T_prior, np.diag([1e-2] * 3 + [1e-2] * 3),
                      pixel_sigma_px=0.3)
    err = invert_transform(T_true) @ res.T_w_c
    assert np.linalg.norm(err[:3, 3]) < 5e-3  # metres, from 6 cm
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(err[:3, :3]).as_rotvec())) < 0.05  # from 0.8 deg
    assert np.all(np.linalg.eigvalsh(res.covariance) > 0)
    assert np.median(res.residual_px[10:]) < 0.5 and np.all(res.whitened_residual[:10] > 20)


def test_normal_equations_match_the_einsum_form():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(50, 2, 2))
    S = A @ np.transpose(A, (0, 2, 1)) + 0.1 * np.eye(2)
    J, r, w = rng.normal(size=(50, 2, 6)), rng.normal(size=(50, 2)), rng.uniform(0, 1, 50)
    S_inv = np.linalg.inv(S)
    H, g = _normal_equations(J, S_inv, w, r)
    JtS = np.transpose(J, (0, 2, 1)) @ S_inv
    np.testing.assert_allclose(H, np.einsum("n,nij,njk->ik", w, JtS, J), rtol=1e-10)
    np.testing.assert_allclose(g, np.einsum("n,nij,nj->i", w, JtS, r), rtol=1e-10)
