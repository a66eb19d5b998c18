"""The two-view relative depth sigma in closed form against the N-view triangulation's, on a
synthetic scene of known truth (fixed seeds)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from triangulation import MultiviewSettings, TrackStatus, triangulate_tracks, two_view_relative_sigma
from vio_core import Camera, ShapeError

CAM = Camera(fx=458.0, fy=457.0, cx=367.0, cy=248.0, width=752, height=480)
C_B = np.diag([1e-6, 2e-6, 1e-6, 4e-5, 1e-5, 2e-5])  # rad^2, m^2


def _pair(baseline_m: float, n: int, seed: int):
    rng = np.random.default_rng(seed)
    P = np.c_[rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(2, 9, n)]
    T_a, T_b = np.eye(4), np.eye(4)
    T_b[:3, :3] = Rotation.from_rotvec([0.01, -0.03, 0.005]).as_matrix()
    T_b[:3, 3] = [baseline_m, 0.01, 0.02]

    def project(T):
        p = (P - T[:3, 3]) @ T[:3, :3]
        return np.c_[CAM.fx * p[:, 0] / p[:, 2] + CAM.cx, CAM.fy * p[:, 1] / p[:, 2] + CAM.cy]

    return project(T_a) + rng.normal(0, 0.7, (n, 2)), project(T_b) + rng.normal(0, 0.7, (n, 2)), T_a, T_b


def _multiview(uv_a, uv_b, T_a, T_b):
    n = len(uv_a)
    res = triangulate_tracks(np.tile(np.arange(n), 2), np.repeat([0, 1], n), np.concatenate([uv_a, uv_b]),
                             CAM, np.stack([T_a, T_b]), MultiviewSettings(), np.stack([1e-12 * np.eye(6), C_B]))
    ok = np.isin(res.status, (TrackStatus.VALID, TrackStatus.UNCERTAIN, TrackStatus.DEPTH_RANGE))
    return np.where(ok[res.obs_track[n:]], res.sigma_depth[n:] / res.depth[n:], np.nan)


@pytest.mark.parametrize("baseline_m", [0.1, 0.3])
def test_it_agrees_with_the_multiview_triangulation_where_a_keyframe_is_decided(baseline_m):
    """Median relative sigmas 0.07-0.2 (the keyframe threshold is 0.12): within 2 % of the
    N-view triangulation's (which refines the point by Gauss-Newton; here the rays' midpoint),
    and match by match within 5 % for 90 % of the matches."""
    uv_a, uv_b, T_a, T_b = _pair(baseline_m, 300, seed=1)
    ref = _multiview(uv_a, uv_b, T_a, T_b)
    got = two_view_relative_sigma(uv_a, uv_b, CAM, CAM, T_a, T_b, C_B)
    assert 0.05 < np.nanmedian(ref) < 0.25
    assert np.nanmedian(got) == pytest.approx(np.nanmedian(ref), rel=0.02)
    both = np.isfinite(ref) & np.isfinite(got)
    assert both.sum() >= 290
    assert np.mean(np.abs(got[both] / ref[both] - 1) < 0.05) >= 0.9


def test_outliers_points_behind_and_no_parallax_are_nan():
    uv_a, uv_b, T_a, T_b = _pair(0.2, 40, seed=2)
    uv_b[:3] += 25.0  # 25 px off their epipolar lines
    got = two_view_relative_sigma(uv_a, uv_b, CAM, CAM, T_a, T_b, C_B)
    assert np.all(np.isnan(got[:3])) and np.all(np.isfinite(got[3:]))
    same = two_view_relative_sigma(uv_a, uv_a, CAM, CAM, T_a, T_a, C_B)  # one viewpoint: no parallax
    assert np.all(np.isnan(same))
    T_back = T_b.copy()
    T_back[:3, :3] = T_b[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # view b turned around: the rays meet behind it
    assert np.all(np.isnan(two_view_relative_sigma(uv_a, uv_b, CAM, CAM, T_a, T_back, C_B)))
    assert two_view_relative_sigma(np.zeros((0, 2)), np.zeros((0, 2)), CAM, CAM, T_a, T_b, C_B).shape == (0,)
    with pytest.raises(ShapeError):
        two_view_relative_sigma(uv_a, uv_b[:5], CAM, CAM, T_a, T_b, C_B)
    with pytest.raises(ShapeError):
        two_view_relative_sigma(uv_a, uv_b, CAM, CAM, T_a, T_b, np.eye(3))


def test_a_wider_baseline_and_a_smaller_pose_covariance_give_a_smaller_sigma():
    uv_a, uv_b, T_a, T_b = _pair(0.1, 200, seed=3)
    wide = _pair(0.4, 200, seed=3)
    base = np.nanmedian(two_view_relative_sigma(uv_a, uv_b, CAM, CAM, T_a, T_b, C_B))
    assert np.nanmedian(two_view_relative_sigma(*wide[:2], CAM, CAM, *wide[2:], C_B)) < 0.5 * base
    assert np.nanmedian(two_view_relative_sigma(uv_a, uv_b, CAM, CAM, T_a, T_b, C_B / 100)) < base
