"""Relative poses and their covariance from the odometry's pose history, against hand-built
truth and Monte Carlo sampling of the window's joint distribution."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.geometry import invert_transform, make_transform
from vio_depth.vio import PoseHistory


def _exp(xi):
    return make_transform(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])


def _log(T):
    return np.r_[Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]]


def _poses(n, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack([make_transform(Rotation.from_rotvec(0.3 * rng.normal(size=3)).as_matrix(),
                                    [0.4 * k, 0.1 * rng.normal(), 0.05 * k]) for k in range(n)])


def _spd(n, scale, seed=1):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.2 * np.eye(n))


def _monte_carlo(T, S, a, b, n=10000, seed=2):
    """Empirical covariance of log((T_a Exp(xi_a))^-1 (T_b Exp(xi_b)) ...) around the mean relative pose."""
    rng = np.random.default_rng(seed)
    xi = rng.multivariate_normal(np.zeros(len(S)), S, size=n)
    T_ab = invert_transform(T[a]) @ T[b]
    err = []
    for x in xi:
        Ta, Tb = T[a] @ _exp(x[6 * a:6 * a + 6]), T[b] @ _exp(x[6 * b:6 * b + 6])
        err.append(_log(invert_transform(T_ab) @ invert_transform(Ta) @ Tb))
    return np.cov(np.array(err).T)


def test_relative_covariance_of_two_window_keyframes_matches_sampling():
    T = _poses(3)
    S = _spd(18, 1e-4)
    h = PoseHistory()
    h.update_keyframes(0, [10, 20, 30], T, S)
    T_ab, C, why = h.relative(10, 30)
    assert why == "" and np.allclose(T_ab, invert_transform(T[0]) @ T[2])
    C_mc = _monte_carlo(T, S, 0, 2)
    np.testing.assert_allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(C_mc)), rtol=0.05)  # first order vs sampled
    # the reverse order is the inverse pose with the covariance mapped accordingly
    T_ba, C_ba, _ = h.relative(30, 10)
    assert np.allclose(T_ba, invert_transform(T_ab))
    A = np.block([[T_ab[:3, :3], np.zeros((3, 3))], [np.zeros((3, 3)), T_ab[:3, :3]]])
    assert np.trace(C_ba) == pytest.approx(np.trace(C), rel=0.5)  # same size, another frame
    assert np.all(np.linalg.eigvalsh(C_ba) > 0) and A.shape == (6, 6)


def test_chain_of_links_outside_the_window():
    """Keyframes that left the window are related through the links as last estimated: with
    independent links the chain covariance is the sum of the transported link covariances."""
    T = _poses(4, seed=3)
    h = PoseHistory()
    blocks = [_spd(6, 1e-4, seed=s) for s in range(4)]
    S = np.zeros((24, 24))
    for k, B in enumerate(blocks):  # independent poses: links are independent too
        S[6 * k:6 * k + 6, 6 * k:6 * k + 6] = B
    h.update_keyframes(0, [1, 2, 3, 4], T, S)
    exact_T, exact_C, _ = h.relative(1, 4)
    # the window moves on: only keyframe 4 remains (and a new one); the links 1-2-3-4 stay
    T2 = np.stack([T[3], T[3] @ _exp(np.r_[0.01, 0, 0, 0.3, 0, 0])])
    h.update_keyframes(0, [4, 5], T2, 1e-6 * np.eye(12))
    chain_T, chain_C, why = h.relative(1, 4)
    assert why == "" and np.allclose(chain_T, exact_T)
    # links are not independent when the poses are (consecutive links share a pose, which makes
    # them anti-correlated): the chain, which leaves the correlations out, is then conservative
    assert np.trace(exact_C) <= np.trace(chain_C) <= 4.0 * np.trace(exact_C)
    # a non-keyframe anchored to keyframe 2 follows it
    T_f = T[1] @ _exp(np.r_[0, 0.02, 0, 0.1, 0, 0])
    h.add_frame(7, 0, 2, T_f, 1e-6 * np.eye(6))
    T_rel, _, _ = h.relative(1, 7)
    assert np.allclose(T_rel, invert_transform(T[0]) @ T_f, atol=1e-9)


def test_refusals_name_the_problem():
    h = PoseHistory()
    h.update_keyframes(0, [1, 2], _poses(2), 1e-4 * np.eye(12))
    h.update_keyframes(1, [8, 9], _poses(2), 1e-4 * np.eye(12))
    _, _, why = h.relative(1, 9)
    assert "re-initialised" in why
    _, _, why = h.relative(1, 5)
    assert "no pose for frame 5" in why
    assert h.sessions() == {0: 2, 1: 2}


def test_history_is_bounded():
    h = PoseHistory(max_frames=5)
    for k in range(20):
        h.update_keyframes(0, [k], _poses(1), np.eye(6) * 1e-4)
    assert len(h) == 5 and h.pose(19) is not None and h.pose(3) is None
