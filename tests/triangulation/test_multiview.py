"""N-view triangulation against exact synthetic geometry: accuracy, uncertainty, outliers,
pose-uncertainty gates, every status, distortion and bad inputs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from triangulation import TriangulationSettings, triangulate_pair
from triangulation.multiview import (
    MultiviewSettings,
    TrackStatus,
    depth_in_view,
    triangulate_tracks,
)
from triangulation.jacobians import pose_jacobian
from vio_core.camera import Camera
from vio_core.errors import InputError, SettingsError
from vio_core.geometry import invert_transform, make_transform

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)


def _poses(n_views=5, step=0.1, seed=0):
    rng = np.random.default_rng(seed)
    return np.array([make_transform(Rotation.from_rotvec(rng.normal(0, 0.02, 3)).as_matrix(),
                                    np.array([step * i, 0.02 * i, 0.01 * i])) for i in range(n_views)])


def _points(n=200, seed=1, z=(2.0, 8.0)):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(*z, n)])


def _observe(points, T, cam=CAM, sigma=0.0, seed=2):
    rng = np.random.default_rng(seed)
    track, view, uv = [], [], []
    for i, Ti in enumerate(T):
        ideal, _ = cam.project((points - Ti[:3, 3]) @ Ti[:3, :3])
        track.append(np.arange(len(points)))
        view.append(np.full(len(points), i))
        uv.append(cam.distort_points(ideal) + sigma * rng.normal(size=ideal.shape))
    return np.concatenate(track), np.concatenate(view), np.concatenate(uv)


def _true_depth(points, T, track, view):
    return np.einsum("nj,nj->n", points[track] - T[view, :3, 3], T[view, :3, 2])


def test_exact_geometry_is_recovered():
    T, P = _poses(), _points()
    res = triangulate_tracks(*_observe(P, T), CAM, T)
    assert np.all(res.valid) and np.all(res.n_inliers == len(T))
    np.testing.assert_allclose(res.points_w, P, atol=1e-6)
    np.testing.assert_allclose(res.depth, _true_depth(P, T, *_observe(P, T)[:2]), rtol=1e-8)
    assert np.all(res.residual_px < 1e-6)


def test_more_views_beat_two_and_sigma_is_calibrated():
    """1 px noise: 5 views give much smaller depth errors than the two-view method on the
    newest pair, and the predicted sigma matches the observed errors (normalised squared
    error ~ 1)."""
    T, P = _poses(5), _points(400)
    track, view, uv = _observe(P, T, sigma=1.0)
    res = triangulate_tracks(track, view, uv, CAM, T, MultiviewSettings(max_relative_sigma=1.0))
    z_true = _true_depth(P, T, track, view)
    first = view == 0
    err_multi = np.abs(res.depth[first] - z_true[first]) / z_true[first]
    # two-view: current = view 0, reference = view 1 (consecutive keyframes)
    T_ref_cur = invert_transform(T[1]) @ T[0]
    two = triangulate_pair(uv[view == 0], uv[view == 1], CAM, CAM, T_ref_cur,
                           TriangulationSettings(max_sampson_px=10, min_angle_deg=0.0))
    err_two = np.abs(two.depth - z_true[first]) / z_true[first]
    assert np.median(err_multi) < 0.4 * np.median(err_two)
    # depth NEES (1 dof) of the 400 points (one view each, independent): the mean of a consistent
    # sigma lies in the 99 % interval of chi2(400) / 400, [0.83, 1.19]; sigma / 3 must fail it
    ok = first & res.inlier
    n = int(ok.sum())
    lo, hi = chi2.ppf(0.005, n) / n, chi2.ppf(0.995, n) / n
    nees = ((res.depth - z_true)[ok] / res.sigma_depth[ok]) ** 2
    consistent = nees.mean()
    assert lo < consistent < hi, (lo, consistent, hi)
    overconfident = (9.0 * nees).mean()  # the same errors against sigma / 3
    assert not lo < overconfident < hi, (lo, overconfident, hi)


def test_outlier_observation_is_dropped_and_track_kept():
    T, P = _poses(5), _points(50)
    track, view, uv = _observe(P, T, sigma=0.3)
    bad = np.nonzero((track == 7) & (view == 2))[0][0]
    uv[bad] += [25.0, -10.0]
    res = triangulate_tracks(track, view, uv, CAM, T)
    assert not res.inlier[bad]
    assert res.inlier.sum() == len(uv) - 1
    assert res.status[7] == TrackStatus.VALID
    assert np.linalg.norm(res.points_w[7] - P[7]) < 0.05 * P[7, 2]


def test_each_track_is_solved_as_if_alone():
    """Tracks are iterated only while they move and re-solved only when they lose an outlier:
    a batch with noisy tracks, outliers and pose uncertainty gives each track the result it
    gets when triangulated alone."""
    T, P = _poses(5), _points(40)
    track, view, uv = _observe(P, T, sigma=0.5, seed=4)
    for k in (3, 11, 12, 30):
        uv[np.nonzero((track == k) & (view == k % 5))[0][0]] += [20.0, -12.0]
    cov = np.tile(np.diag([0.002**2] * 3 + [1e-4] * 3), (5, 1, 1))
    batch = triangulate_tracks(track, view, uv, CAM, T, MultiviewSettings(), cov)
    for k in range(40):
        sel = track == k
        alone = triangulate_tracks(track[sel], view[sel], uv[sel], CAM, T, MultiviewSettings(), cov)
        assert alone.status[0] == batch.status[k]
        np.testing.assert_array_equal(alone.inlier, batch.inlier[sel])
        np.testing.assert_allclose(alone.points_w[0], batch.points_w[k], rtol=0, atol=1e-9)
        np.testing.assert_allclose(alone.sigma_depth, batch.sigma_depth[sel], rtol=1e-9)
    assert not batch.inlier[np.nonzero((track == 3) & (view == 3))[0][0]]


def test_two_views_that_disagree_are_rejected():
    T, P = _poses(2), _points(10)
    track, view, uv = _observe(P, T)
    uv[(track == 3) & (view == 1)] += [0.0, 30.0]  # off the epipolar line: no consistent point
    res = triangulate_tracks(track, view, uv, CAM, T, MultiviewSettings(max_relative_sigma=1.0))
    assert res.status[3] == TrackStatus.REPROJECTION
    assert np.all(res.valid[np.arange(10) != 3])


def test_pose_uncertainty_widens_gate_and_sigma():
    """A pose error inside the stated covariance keeps its observations as inliers, and the
    depth sigma grows with the pose covariance."""
    T, P = _poses(4), _points(100, z=(3.0, 6.0))
    track, view, uv = _observe(P, T, sigma=0.3)
    T_bad = T.copy()
    T_bad[2] = T[2] @ make_transform(Rotation.from_rotvec([0.004, 0.0, 0.0]).as_matrix(), np.zeros(3))  # ~2 px
    exact = triangulate_tracks(track, view, uv, CAM, T_bad, MultiviewSettings(pixel_sigma_px=0.3))
    cov = np.tile(np.diag([0.004**2] * 3 + [1e-6] * 3), (4, 1, 1))
    loose = triangulate_tracks(track, view, uv, CAM, T_bad, MultiviewSettings(pixel_sigma_px=0.3), cov)
    assert (~exact.inlier[view == 2]).mean() > 0.5
    assert loose.inlier.mean() > 0.97
    ok = exact.inlier & loose.inlier
    assert np.all(loose.sigma_depth[ok] > exact.sigma_depth[ok])


def test_statuses():
    T = _poses(3, step=0.5)
    P = np.array([[0.1, 0.0, 4.0], [0.3, 0.2, 3.0], [0.0, 0.0, 500.0], [0.2, 0.1, 0.5]])
    track, view, uv = _observe(P, T)
    keep = ~((track == 1) & (view > 0))  # track 1 seen once
    s = MultiviewSettings(max_relative_sigma=0.05, max_depth_m=1000.0, min_depth_m=1.0)
    res = triangulate_tracks(track[keep], view[keep], uv[keep], CAM, T, s)
    assert list(res.status) == [TrackStatus.VALID, TrackStatus.TOO_FEW_VIEWS, TrackStatus.UNCERTAIN,
                                TrackStatus.DEPTH_RANGE]
    assert res.status_counts()["valid"] == 1
    # identical camera centres (pure rotation): nothing can be triangulated
    R = np.array([make_transform(Rotation.from_rotvec([0, 0.05 * i, 0]).as_matrix(), np.zeros(3)) for i in range(3)])
    res = triangulate_tracks(*_observe(P[:1], R), CAM, R)
    assert res.status[0] == TrackStatus.LOW_PARALLAX and np.all(np.isnan(res.points_w[0]))


def test_behind_camera():
    T = np.array([np.eye(4), make_transform(np.eye(3), [0.5, 0.0, 0.0])])
    # view 0 sees the point straight ahead; view 1 at u = 403 px, where a point 3 m *behind*
    # both cameras would project: the rays meet behind them
    uv = np.array([[320.0, 240.0], [320.0 + 500.0 * 0.5 / 3.0, 240.0]])
    res = triangulate_tracks([0, 0], [0, 1], uv, CAM, T)
    assert res.status[0] == TrackStatus.BEHIND_CAMERA


def test_distorted_camera():
    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0, (-0.2, 0.05, 0.001, -0.001))
    T, P = _poses(4), _points(100)
    res = triangulate_tracks(*_observe(P, T, cam=cam), cam, T)
    assert np.all(res.valid)
    np.testing.assert_allclose(res.points_w, P, atol=1e-4)


def test_depth_in_view():
    P = np.array([[0.0, 0.0, 4.0], [1.0, 0.5, 6.0]])
    C = np.zeros((2, 3, 3))
    T = np.eye(4)
    z, s = depth_in_view(P, C, T)
    np.testing.assert_allclose(z, [4.0, 6.0])
    np.testing.assert_allclose(s, 0.0)
    # translation uncertainty along the optical axis moves every depth by the same sigma
    z, s = depth_in_view(P, C, T, np.diag([0, 0, 0, 0, 0, 0.01**2]))
    np.testing.assert_allclose(s, 0.01)
    # point covariance along the ray
    C[:, 2, 2] = 0.02**2
    z, s = depth_in_view(P, C, T)
    np.testing.assert_allclose(s, 0.02)


def test_pose_jacobian_matches_finite_differences():
    p = np.array([[0.3, -0.2, 4.0]])
    J = pose_jacobian(p)[0]
    T = make_transform(Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix(), [0.5, 0.1, -0.3])
    p_w = T[:3, :3] @ p[0] + T[:3, 3]
    h = 1e-6
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = h
        Tp = T @ make_transform(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])
        p_new = Tp[:3, :3].T @ (p_w - Tp[:3, 3])
        np.testing.assert_allclose((p_new - p[0]) / h, J[:, k], atol=1e-4)


def test_bad_inputs():
    T, P = _poses(2), _points(3)
    track, view, uv = _observe(P, T)
    with pytest.raises(InputError):
        triangulate_tracks(track, np.zeros_like(view), uv, CAM, T)  # two observations in one view
    with pytest.raises(InputError):
        triangulate_tracks(track, view + 5, uv, CAM, T)
    with pytest.raises(InputError):
        triangulate_tracks(track, view, uv, [CAM], T)
    with pytest.raises(SettingsError):
        MultiviewSettings(max_relative_sigma=0)
    res = triangulate_tracks(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), CAM, T)
    assert len(res.track_ids) == 0 and len(res.depth) == 0
