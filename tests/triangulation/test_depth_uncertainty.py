"""Monte-Carlo checks of the first-order depth uncertainty ``sigma_depth``."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from triangulation import TriangulationSettings, triangulate_pair
from vio_core.camera import Camera
from vio_core.geometry import invert_transform, make_transform, transform_points

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
T_REF_CUR = invert_transform(make_transform(Rotation.from_rotvec([0.05, -0.3, 0.1]).as_matrix(),
                                            [-1.0, 0.1, -0.3]))
LOOSE = dict(max_sampson_px=1e6, max_reprojection_px=1e6, min_angle_deg=0.0, max_depth_m=1e6)
TRIALS = 400  # std estimate of one point: ~3.5 % relative (1 / sqrt(2 * TRIALS))
TOLERANCE = 0.20  # every point: empirical std within 20 % of sigma_depth


def _scene(n=40, seed=0):
    rng = np.random.default_rng(seed)
    uv = np.column_stack([rng.uniform(40, 600, n), rng.uniform(40, 440, n)])
    pts = CAM.backproject(uv, rng.uniform(4.0, 12.0, n))
    uc, _ = CAM.project(pts)
    ur, _ = CAM.project(transform_points(T_REF_CUR, pts))
    return pts, uc, ur


def _perturbed_pose(T, xi):
    """``T * Exp(xi)`` to first order as documented: ``R Exp(w)``, ``t + R rho``."""
    out = T.copy()
    out[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(xi[:3]).as_matrix()
    out[:3, 3] = T[:3, 3] + T[:3, :3] @ xi[3:]
    return out


def test_pixel_noise_monte_carlo():
    sigma_px = 0.7
    pts, uc, ur = _scene()
    settings = TriangulationSettings(pixel_sigma_px=sigma_px, **LOOSE)
    pred = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR, settings).sigma_depth
    rng = np.random.default_rng(1)
    n = len(pts)
    noisy = triangulate_pair(np.tile(uc, (TRIALS, 1)) + rng.normal(0, sigma_px, (TRIALS * n, 2)),
                             np.tile(ur, (TRIALS, 1)) + rng.normal(0, sigma_px, (TRIALS * n, 2)),
                             CAM, CAM, T_REF_CUR, settings)
    emp = noisy.depth.reshape(TRIALS, n).std(axis=0)
    ratio = emp / pred
    assert np.all(np.abs(ratio - 1) < TOLERANCE), ratio
    assert abs(np.median(ratio) - 1) < 0.07
    # the predicted uncertainty varies a lot across points, so the test is not trivial
    assert pred.max() / pred.min() > 3
    # and it scales linearly with the pixel noise
    half = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR,
                            TriangulationSettings(pixel_sigma_px=sigma_px / 2, **LOOSE)).sigma_depth
    np.testing.assert_allclose(half, pred / 2, rtol=1e-6)


def test_pose_covariance_monte_carlo():
    pts, uc, ur = _scene(seed=2)
    cov = np.diag([2e-3**2, 1e-3**2, 1.5e-3**2, 0.02**2, 0.01**2, 0.03**2])
    cov[0, 4] = cov[4, 0] = 0.5 * 2e-3 * 0.01  # a correlated pair
    no_px = TriangulationSettings(pixel_sigma_px=0.0, **LOOSE)
    pred = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR, no_px, pose_covariance=cov).sigma_depth
    assert np.all(pred > 0)
    L = np.linalg.cholesky(cov)
    rng = np.random.default_rng(3)
    depths = np.array([
        triangulate_pair(uc, ur, CAM, CAM, _perturbed_pose(T_REF_CUR, L @ rng.normal(size=6)), no_px).depth
        for _ in range(TRIALS)
    ])
    ratio = depths.std(axis=0) / pred
    assert np.all(np.abs(ratio - 1) < TOLERANCE), ratio
    assert abs(np.median(ratio) - 1) < 0.07


def test_pixel_and_pose_terms_add_in_variance():
    _, uc, ur = _scene(seed=4)
    cov = np.diag([1e-3**2] * 3 + [0.01**2] * 3)
    px = TriangulationSettings(pixel_sigma_px=1.0)
    s_px = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR, px).sigma_depth
    s_pose = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR, TriangulationSettings(pixel_sigma_px=0.0),
                              pose_covariance=cov).sigma_depth
    s_both = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR, px, pose_covariance=cov).sigma_depth
    np.testing.assert_allclose(s_both**2, s_px**2 + s_pose**2, rtol=1e-9)
    zero = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR, TriangulationSettings(pixel_sigma_px=0.0)).sigma_depth
    np.testing.assert_array_equal(zero, 0.0)


def test_uncertainty_shrinks_with_baseline():
    rng = np.random.default_rng(5)
    pts = CAM.backproject(np.column_stack([rng.uniform(40, 600, 30), rng.uniform(40, 440, 30)]),
                          rng.uniform(5.0, 10.0, 30))
    sigmas = []
    for baseline in (0.5, 1.0, 2.0):
        T = invert_transform(make_transform(np.eye(3), [baseline, 0.0, 0.0]))
        uc, _ = CAM.project(pts)
        ur, _ = CAM.project(transform_points(T, pts))
        res = triangulate_pair(uc, ur, CAM, CAM, T, TriangulationSettings())
        assert np.all(res.valid)
        sigmas.append(res.sigma_depth)
    # depth error ~ z^2 sigma / (f b): halving the baseline roughly doubles it
    assert np.all(sigmas[0] > sigmas[1]) and np.all(sigmas[1] > sigmas[2])
    np.testing.assert_allclose(sigmas[0] / sigmas[1], 2.0, rtol=0.15)


def test_pose_jacobian_equals_central_differences_of_whole_triangulations():
    # reference: one full triangulate_pair per perturbed pose T * Exp(+-h e_k), the
    # implementation the batched Jacobian replaced; noisy pixels, so the optimal correction
    # moves every match. Same steps, same arithmetic per pose: equal to float noise.
    h = 1e-6
    pts, uc, ur = _scene(n=200, seed=6)
    rng = np.random.default_rng(7)
    uc, ur = uc + rng.normal(0, 0.8, uc.shape), ur + rng.normal(0, 0.8, ur.shape)
    settings = TriangulationSettings(**LOOSE)
    res = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR, settings, pose_covariance=np.eye(6))
    ref = np.empty((len(uc), 6))
    for k in range(6):
        z = [triangulate_pair(uc, ur, CAM, CAM, _perturbed_pose(T_REF_CUR, s * h * np.eye(6)[k]), settings).depth
             for s in (1.0, -1.0)]
        ref[:, k] = (z[0] - z[1]) / (2 * h)
    assert np.all(res.valid) and np.all(np.isfinite(ref))
    np.testing.assert_allclose(res.depth_pose_jacobian, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
