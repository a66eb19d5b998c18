"""The chi-square test of a stated relative pose against its matches, and the online inflation."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from triangulation import ConsistencySettings, PoseConsistency, PoseInflation, pose_consistency
from vio_core.camera import Camera
from vio_core.errors import SettingsError

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
COV = np.diag([math.radians(0.1) ** 2] * 3 + [0.005**2] * 3)


def _scene(rng, n=300, noise_px=0.5, T=None):
    P = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2, 6, n)])
    if T is None:
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec([0.01, 0.05, 0.0]).as_matrix()
        T[:3, 3] = [0.2, 0.0, 0.02]  # T_ref_cur

    def proj(Pc):
        u = Pc @ CAM.K.T
        return u[:, :2] / u[:, 2:]

    uc = proj(P) + rng.normal(0, noise_px, (n, 2))
    ur = proj(P @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, noise_px, (n, 2))
    return uc, ur, T


def _perturb(T, xi):
    out = T.copy()
    out[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(xi[:3]).as_matrix()
    out[:3, 3] = T[:3, 3] + T[:3, :3] @ xi[3:]
    return out


def test_chi2_of_a_pose_with_its_stated_error_is_chi_square_5():
    rng = np.random.default_rng(0)
    chis = []
    for _ in range(150):
        uc, ur, T = _scene(rng)
        c = pose_consistency(uc, ur, CAM, CAM, _perturb(T, rng.multivariate_normal(np.zeros(6), COV)), COV)
        assert c.dof == 5  # the images see rotation and direction, not the baseline's length
        chis.append(c.chi2)
    chis = np.array(chis)
    assert 4.0 < chis.mean() < 6.0  # E[chi2(5)] = 5
    assert np.mean(chis > ConsistencySettings().threshold(5)) < 0.02  # refused at most ~0.1 %


def test_a_pose_five_times_worse_than_stated_is_seen_and_its_factor_estimated():
    rng = np.random.default_rng(1)
    factors, refused = [], 0
    infl = PoseInflation(ConsistencySettings(max_inflation=30.0, window=60))
    for _ in range(60):
        uc, ur, T = _scene(rng)
        c = pose_consistency(uc, ur, CAM, CAM, _perturb(T, rng.multivariate_normal(np.zeros(6), 9 * COV)), COV)
        factors.append(c.variance_factor)
        refused += c.chi2 > ConsistencySettings().threshold(c.dof)
        infl.update(c)
    assert 4 < np.median(factors) < 16  # k^2 = 9
    assert refused > 10
    # pooled, the inflation tells the standard deviations are 3x too small
    assert 2.5 < infl.value < 3.5


def _tested(d, S=np.eye(5), C=0.01 * np.eye(5)):
    return PoseConsistency(100, 5, 0.0, 0.0, 0.0, 0.0, 0.5, terms=(np.asarray(d, float), S, C))


def test_inflation_never_below_one_and_capped():
    infl = PoseInflation(ConsistencySettings(max_inflation=3.0))
    assert infl.value == 1.0
    for _ in range(10):
        infl.update(_tested(np.full(5, 0.1)))  # images agree better than stated
    assert infl.value == 1.0
    for _ in range(10):
        infl.update(_tested(np.full(5, 100.0)))  # far beyond the stated uncertainty
    assert infl.value == 3.0
    infl.update(PoseConsistency.untested())
    assert infl.value == 3.0
    infl.reset()
    assert infl.value == 1.0


def test_untested_without_baseline_or_matches_and_exact_pose_refused_when_wrong():
    rng = np.random.default_rng(2)
    uc, ur, T = _scene(rng)
    T0 = T.copy()
    T0[:3, 3] = 0.0
    assert not pose_consistency(uc, ur, CAM, CAM, T0, COV).tested
    assert not pose_consistency(uc[:5], ur[:5], CAM, CAM, T, COV).tested
    # stated exact (None) and right: a small chi2; stated exact and 0.5 deg off: refused
    assert pose_consistency(uc, ur, CAM, CAM, T, None).chi2 < 20
    bad = pose_consistency(uc, ur, CAM, CAM, _perturb(T, np.r_[0.0, math.radians(0.5), 0.0, 0, 0, 0]), None)
    assert bad.chi2 > 100 and bad.variance_factor == math.inf and bad.rotation_deg > 0.3
    assert "deg rotation" in bad.describe()


def test_settings_are_validated():
    with pytest.raises(SettingsError):
        ConsistencySettings(refuse_probability=1.0)
    with pytest.raises(SettingsError):
        ConsistencySettings(max_inflation=0.5)
    with pytest.raises(SettingsError):
        ConsistencySettings(max_residual_px=float("nan"))


def test_inflation_pools_pairs_of_different_dof_by_the_documented_equation():
    # pairs seeing 3, 5 and 6 dof (solved in stacked groups), some Winsorised: the returned k
    # solves sum_i min(d_i^T (k^2 S_i + C_i)^-1 d_i, cap_i) + r0 / k^2 = sum_i r_i + r0
    rng = np.random.default_rng(3)
    settings = ConsistencySettings(max_inflation=10.0)
    infl = PoseInflation(settings)
    terms = []
    for i in range(12):
        m = (3, 5, 6)[i % 3]
        S = np.diag(rng.uniform(0.5, 2.0, m))
        C = 0.1 * np.eye(m)
        d = rng.normal(0, 2.0, m) * np.sqrt(np.diag(S)) * (30.0 if i == 4 else 1.0)  # pair 4: a gross fault
        terms.append((d, S, C))
        infl.update(PoseConsistency(100, m, 0.0, 0.0, 0.0, 0.0, 0.5, terms=(d, S, C)))
    k2 = infl.value**2
    assert 1.0 < infl.value < settings.max_inflation

    def total(k2):
        return sum(min(float(d @ np.linalg.solve(k2 * S + C, d)), settings.threshold(len(d)))
                   for d, S, C in terms) + settings.prior_pairs * np.mean([len(d) for d, _, _ in terms]) / k2

    target = sum(len(d) for d, _, _ in terms) * (1 + settings.prior_pairs / len(terms))
    assert total(k2 / 1.001) >= target >= total(k2)  # bracketed to the bisection's tolerance
