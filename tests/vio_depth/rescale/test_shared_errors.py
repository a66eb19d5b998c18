"""The fit knows that a pose error moves all points of a pair together (issue 20, item 3).

Points triangulated with a relative pose drawn from its stated covariance: their depth
errors are shared, so the fit's predicted error must not shrink with the number of points.
With ``depth_shared`` the prediction matches a Monte Carlo of the actual error; without it
(the old model) it is several times too small -- the "confidently wrong" failure.
"""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from triangulation import TriangulationSettings, triangulate_pair
from vio_core.camera import Camera
from vio_depth.rescale import FitStatus, expected_relative_error, fit_affine, fit_scale_only, shared_depth_errors

CAM = Camera(640, 480, 525.0, 525.0, 320.0, 240.0)
D_MAP = np.linspace(0.25, 1.0, 100 * 100).reshape(100, 100)  # exact disparity = 1/depth, 1-4 m


def _trial(rng, P, T, cov, uc, ur):
    xi = rng.multivariate_normal(np.zeros(6), cov)
    Tn = T.copy()
    Tn[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(xi[:3]).as_matrix()
    Tn[:3, 3] = T[:3, 3] + T[:3, :3] @ xi[3:]
    p = triangulate_pair(uc + rng.normal(0, 0.5, uc.shape), ur + rng.normal(0, 0.5, ur.shape), CAM, CAM, Tn,
                         TriangulationSettings(), pose_covariance=cov)
    v = p.valid
    d = 1.0 / P[v, 2]  # the true (affine-invariant) disparity, exact: any error is the rescaling's
    shared = shared_depth_errors(p.depth_pose_jacobian[v], cov)
    return fit_affine(d, p.depth[v], p.sigma_depth[v], depth_shared=shared), fit_affine(d, p.depth[v], p.sigma_depth[v])


def test_predicted_error_with_shared_pose_errors_matches_a_monte_carlo():
    rng = np.random.default_rng(1)
    n = 150
    P = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1, 1, n), rng.uniform(1, 4, n)])
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.05, 0.0]).as_matrix()
    T[:3, 3] = [0.2, 0.0, 0.02]
    u = P @ CAM.K.T
    uc = u[:, :2] / u[:, 2:]
    v = (P @ T[:3, :3].T + T[:3, 3]) @ CAM.K.T
    ur = v[:, :2] / v[:, 2:]
    cov = np.diag([math.radians(0.15) ** 2] * 3 + [0.004**2] * 3)
    actual, predicted, old = [], [], []
    for _ in range(80):
        fit, naive = _trial(rng, P, T, cov, uc, ur)
        if not (fit.ok and naive.ok):
            continue
        m = fit.alpha * D_MAP + fit.beta
        actual.append(np.median(np.abs(D_MAP / m - 1.0)))  # true depth 1/d against 1/m
        predicted.append(expected_relative_error(D_MAP, fit.alpha, fit.beta, fit.covariance))
        old.append(expected_relative_error(D_MAP, naive.alpha, naive.beta, naive.covariance))
        assert np.all(np.diag(fit.shared_covariance) > 0) and not np.any(naive.shared_covariance)
    assert len(actual) > 60
    ratio = np.mean(predicted) / np.mean(actual)
    assert 0.7 < ratio < 1.4, ratio  # calibrated
    assert np.mean(old) < 0.4 * np.mean(actual)  # the model without shared errors: confidently wrong


def test_scale_only_fit_carries_the_shared_error_too():
    rng = np.random.default_rng(4)
    z = rng.uniform(1, 4, 100)
    S = np.column_stack([0.03 * z, np.zeros(100)])  # a 3 % common scale error
    fit = fit_scale_only(1.0 / z, z, 0.0, sigma_depth=0.01 * z, depth_shared=S)
    assert fit.ok
    rel = math.sqrt(fit.shared_covariance[0, 0]) / fit.alpha
    assert rel == pytest.approx(0.03, rel=0.05)


def test_a_line_that_explains_nothing_is_never_ok():
    """R^2 <= 0 (the issue saw -2.2 on an ``ok`` frame): a scale-only fit forced through a
    wrong beta explains less of the points' spread than their mean does -- refused."""
    rng = np.random.default_rng(5)
    d = rng.uniform(0.2, 1.0, 200)
    z = 1.0 / (d + 0.05)
    good = fit_scale_only(d, z, 0.05, sigma_depth=0.3 * z)
    assert good.ok and good.r2 > 0.99
    bad = fit_scale_only(d, z, 0.8, sigma_depth=0.3 * z)
    assert bad.r2 <= 0 and bad.status == FitStatus.NO_CONSENSUS and "R^2" in bad.reason
