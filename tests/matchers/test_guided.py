"""Pose-guided matching: a synthetic two-view scene with known poses and descriptors.

Every 3D point has its own random non-negative unit descriptor, seen in both images with a
little noise; the true correspondence of each keypoint is known. Tolerances are stated where
used.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from matchers import EpipolarPrior, Features, GuidedSettings, PoseGuidedMatcher, SiftMatcher, SiftSettings
from matchers.guided import band_pairs, band_half_widths, epipolar_lines, guided_ratio_match
from matchers.sift import ratio_match
from vio_core.camera import Camera
from vio_core.errors import SettingsError, ShapeError

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)


def _pose(rvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float))[0]
    T[:3, 3] = t
    return T


#: camera a in camera b: 0.4 m sideways and a little forward, 3 degrees of rotation
T_B_A = _pose([0.01, 0.05, -0.01], [-0.4, 0.02, 0.1])


def _project(T_c_w, points_w):
    p = points_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    return np.column_stack([CAM.fx * p[:, 0] / p[:, 2] + CAM.cx, CAM.fy * p[:, 1] / p[:, 2] + CAM.cy])


def _unit(d):
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


def _scene(n=400, seed=0):
    """Keypoints and descriptors of ``n`` points seen by camera a (world frame) and camera b."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([20, 20], [620, 460], (n, 2))
    depth = rng.uniform(4.0, 12.0, n)
    points = np.column_stack([(uv[:, 0] - CAM.cx) / CAM.fx, (uv[:, 1] - CAM.cy) / CAM.fy, np.ones(n)]) * depth[:, None]
    uv_b = _project(T_B_A, points)
    desc = rng.random((n, 128)) ** 4  # sparse-ish, non-negative, like SIFT histograms
    desc_a = _unit(desc + 0.02 * rng.random((n, 128)))
    desc_b = _unit(desc + 0.02 * rng.random((n, 128)))
    noise = rng.normal(0.0, 0.3, (n, 2))
    return uv, uv_b + noise, desc_a, desc_b


def _prior(covariance=None):
    return EpipolarPrior(CAM, CAM, T_B_A, covariance)


def _cov(rot_deg, trans_m):
    return np.diag([np.radians(rot_deg) ** 2] * 3 + [trans_m**2] * 3)


def test_guided_keeps_the_true_matches_and_only_those():
    uv_a, uv_b, da, db = _scene()
    m = guided_ratio_match(da, db, uv_a, uv_b, _prior(), GuidedSettings(enabled=True))
    assert len(m) >= 0.97 * len(uv_a)  # the descriptors are distinct: nearly every point matches
    np.testing.assert_array_equal(m.idx_a, m.idx_b)  # and every match is the true one
    plain = ratio_match(da, db)
    assert len(m) >= len(plain)


def test_planted_wrong_match_outside_the_band_is_rejected():
    uv_a, uv_b, da, db = _scene()
    i0 = 7
    # point i0 is occluded in b; a look-alike (its descriptor, slightly changed) sits 60 px off its epipolar line
    lines, _ = epipolar_lines(_prior(), uv_a[i0:i0 + 1])
    normal = lines[0, :2] / np.linalg.norm(lines[0, :2])
    decoy_uv = uv_b[i0] + 60.0 * normal
    rng = np.random.default_rng(1)
    decoy = _unit(da[i0:i0 + 1] + 0.01 * rng.random((1, 128)))
    keep = np.arange(len(uv_b)) != i0
    uv_b2, db2 = np.vstack([uv_b[keep], decoy_uv]), np.vstack([db[keep], decoy])
    decoy_idx = len(uv_b2) - 1

    plain = ratio_match(da, db2)
    assert decoy_idx in plain.idx_b[plain.idx_a == i0]  # exhaustive NN + ratio + mutual accepts it

    distance, half = band_half_widths(_prior(), uv_a[i0:i0 + 1], decoy_uv[None], GuidedSettings())
    assert distance[0, 0] > half[0, 0]  # the decoy is outside i0's band
    guided = guided_ratio_match(da, db2, uv_a, uv_b2, _prior(), GuidedSettings(enabled=True))
    assert i0 not in guided.idx_a
    assert decoy_idx not in guided.idx_b


def test_a_pose_error_within_the_stated_covariance_keeps_the_matches():
    """The matches of a pose that is off by about its stated sigma survive only with the covariance."""
    uv_a, uv_b, da, db = _scene()
    cov = _cov(0.3, 0.02)
    wrong = _pose([0.01 + np.radians(0.3), 0.05, -0.01], [-0.4, 0.02, 0.1]) @ np.eye(4)
    wrong_prior = EpipolarPrior(CAM, CAM, wrong, cov)
    s = GuidedSettings(enabled=True, floor_px=1.5)
    with_cov = guided_ratio_match(da, db, uv_a, uv_b, wrong_prior, s)
    without = guided_ratio_match(da, db, uv_a, uv_b, EpipolarPrior(CAM, CAM, wrong), s)
    assert len(with_cov) >= 0.97 * len(uv_a)
    assert len(without) < 0.8 * len(with_cov)  # a 0.3 degree error moves lines by ~2.6 px at f = 500
    np.testing.assert_array_equal(with_cov.idx_a, with_cov.idx_b)


def test_band_grows_with_the_pose_covariance():
    uv_a, uv_b, _, _ = _scene(50)
    s = GuidedSettings(floor_px=2.0, sigmas=3.0)
    _, exact = band_half_widths(_prior(), uv_a, uv_b, s)
    np.testing.assert_allclose(exact, 2.0)
    _, one = band_half_widths(_prior(_cov(0.1, 0.01)), uv_a, uv_b, s)
    _, four = band_half_widths(_prior(4 * _cov(0.1, 0.01)), uv_a, uv_b, s)
    assert np.all(one > exact)
    np.testing.assert_allclose(four - 2.0, 2 * (one - 2.0), rtol=1e-9)  # sigma scales with sqrt(covariance)


def test_line_sigma_matches_monte_carlo_pose_errors():
    """The first-order sigma of the line at the true match agrees with sampled poses within 10 %."""
    uv_a, uv_b, _, _ = _scene(20, seed=3)
    # correlated rotation and translation errors, different per axis: the signs and the order of
    # the Jacobian's blocks matter
    L = np.random.default_rng(4).normal(size=(6, 6)) * np.r_[[np.radians(0.2)] * 3, [0.01] * 3][:, None]
    cov = L @ L.T
    lines, line_cov = epipolar_lines(_prior(cov), uv_a)
    xb = np.column_stack([uv_b, np.ones(len(uv_b))])
    predicted = np.sqrt(np.einsum("nk,nkl,nl->n", xb, line_cov, xb))
    rng = np.random.default_rng(5)
    xi = rng.multivariate_normal(np.zeros(6), cov, 4000)
    d = np.empty((len(xi), len(uv_a)))
    for k, (w, v) in enumerate(zip(xi[:, :3], xi[:, 3:])):
        T = T_B_A.copy()  # right perturbation T Exp(xi), first order in the translation
        T[:3, :3] = T_B_A[:3, :3] @ cv2.Rodrigues(w)[0]
        T[:3, 3] = T_B_A[:3, 3] + T_B_A[:3, :3] @ v
        lk, _ = epipolar_lines(EpipolarPrior(CAM, CAM, T), uv_a)
        d[k] = np.einsum("nk,nk->n", lk, xb)
    np.testing.assert_allclose(d.std(axis=0), predicted, rtol=0.1)


def test_sift_matcher_with_pose_equals_plain_matching_when_off():
    uv_a, uv_b, da, db = _scene()
    fa = Features(uv_a.astype(np.float32), da, np.ones(len(da), np.float32), (640, 480))
    fb = Features(uv_b.astype(np.float32), db, np.ones(len(db), np.float32), (640, 480))
    off = SiftMatcher()
    assert isinstance(off, PoseGuidedMatcher)
    a, b = off.match(fa, fb), off.match_with_pose(fa, fb, _prior())
    for x, y in ((a.idx_a, b.idx_a), (a.idx_b, b.idx_b), (a.confidence, b.confidence)):
        np.testing.assert_array_equal(x, y)
    on = SiftMatcher(SiftSettings(guided=GuidedSettings(enabled=True)))
    g = on.match_with_pose(fa, fb, _prior())
    np.testing.assert_array_equal(g.idx_a, g.idx_b)
    # no baseline: no epipolar geometry, plain matching
    no_t = EpipolarPrior(CAM, CAM, _pose([0.01, 0.05, -0.01], [0, 0, 0]))
    np.testing.assert_array_equal(on.match_with_pose(fa, fb, no_t).idx_a, a.idx_a)


def test_dense_and_sparse_band_paths_agree():
    """A wide band (dense path) gives the same matches as the per-pair path up to float32 rounding."""
    uv_a, uv_b, da, db = _scene()
    wide = GuidedSettings(floor_px=400.0)  # almost every pair: the masked matrix product
    narrow_all = guided_ratio_match(da, db, uv_a, uv_b, _prior(), GuidedSettings(floor_px=3.0))
    dense = guided_ratio_match(da, db, uv_a, uv_b, _prior(), wide)
    plain = ratio_match(da, db)
    assert set(zip(dense.idx_a, dense.idx_b)) == set(zip(plain.idx_a, plain.idx_b))
    assert set(zip(plain.idx_a, plain.idx_b)) <= set(zip(narrow_all.idx_a, narrow_all.idx_b))


def test_shapes_and_settings_are_checked():
    uv_a, uv_b, da, db = _scene(20)
    with pytest.raises(ShapeError):
        guided_ratio_match(da, db, uv_a[:-1], uv_b, _prior(), GuidedSettings())
    with pytest.raises(ShapeError):
        guided_ratio_match(da, db[:, :64], uv_a, uv_b, _prior(), GuidedSettings())
    with pytest.raises(ShapeError):
        EpipolarPrior(CAM, CAM, T_B_A, np.eye(5))
    with pytest.raises(ShapeError):
        EpipolarPrior(CAM, CAM, np.eye(3))
    for bad in ({"floor_px": 0.0}, {"floor_px": float("inf")}, {"sigmas": -1.0}, {"block_rows": 0},
                {"enabled": "yes"}):
        with pytest.raises(SettingsError):
            GuidedSettings(**bad)


@pytest.mark.parametrize("t", [[0.0, 0.0, 1.0],  # forward: the epipole inside the image
                               [2.0, 0.0, 0.0],  # sideways: the epipole at infinity
                               [-0.4, 0.02, 0.1],  # the epipole outside the image, finite
                               [0.3, -0.2, -1.0]])  # backward
@pytest.mark.parametrize("covariance", [None, "cov"])
def test_the_band_search_finds_exactly_the_dense_band(t, covariance):
    """The ring/angle search (blocks of lines sorted by angle) returns every pair of the dense
    band test, and nothing else, whatever the epipole's position."""
    uv_a, uv_b, da, db = _scene(300, seed=2)
    T = _pose([0.01, -0.02, 0.005], t)
    cov = None if covariance is None else _cov(0.05, 0.01)
    prior = EpipolarPrior(CAM, CAM, T, cov)
    s = GuidedSettings(block_rows=16)
    distance, half = band_half_widths(prior, uv_a, uv_b, s)
    want = set(zip(*np.nonzero(distance <= half)))
    rows, cols, sims = band_pairs(prior, uv_a, uv_b, s, da, db)
    assert set(zip(rows.tolist(), cols.tolist())) == want and len(rows) == len(want)
    assert np.all(np.diff(rows) >= 0)  # grouped by row
    np.testing.assert_allclose(sims, np.einsum("ij,ij->i", da[rows], db[cols]), atol=1e-5)


def _reference_guided(da, db, uv_a, uv_b, prior, settings, ratio=0.8):
    """Guided matching written plainly: the dense band mask over the full similarity matrix."""
    distance, half = band_half_widths(prior, uv_a, uv_b, settings)
    sims = np.where(distance <= half, da.astype(np.float64) @ db.T.astype(np.float64), -np.inf)
    matches = []
    for i in range(len(da)):
        row = sims[i]
        if not np.isfinite(row).any():
            continue
        j = int(np.argmax(row))
        s2 = np.max(np.delete(row, j)) if len(row) > 1 else -np.inf
        col = sims[:, j]
        i_back = int(np.argmax(col))
        t2 = np.max(np.delete(col, i_back))
        d = lambda s: np.sqrt(max(2 - 2 * (0.0 if not np.isfinite(s) else s), 0.0))  # noqa: E731
        if i_back == i and d(row[j]) < ratio * d(s2) and d(col[i]) < ratio * d(t2):
            matches.append((i, j))
    return matches


@pytest.mark.parametrize("t", [[0.0, 0.0, 1.0], [-0.4, 0.02, 0.1]])
@pytest.mark.parametrize("floor_px", [3.0, 40.0])
def test_guided_matches_equal_a_plain_dense_reference(t, floor_px):
    """Matches equal those of the band mask applied to the full similarity matrix (narrow and
    wide bands; repeated descriptors make the ratio test matter)."""
    uv_a, uv_b, da, db = _scene(200, seed=4)
    rng = np.random.default_rng(6)
    db[::7] = _unit(db[::7][rng.permutation(len(db[::7]))] + 0.05 * rng.random((len(db[::7]), 128)))
    prior = EpipolarPrior(CAM, CAM, _pose([0.01, -0.02, 0.005], t), _cov(0.05, 0.01))
    s = GuidedSettings(floor_px=floor_px, block_rows=16)
    m = guided_ratio_match(da, db, uv_a, uv_b, prior, s)
    assert list(zip(m.idx_a.tolist(), m.idx_b.tolist())) == _reference_guided(da, db, uv_a, uv_b, prior, s)
