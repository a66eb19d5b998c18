"""Two-view triangulation against exact synthetic geometry: accuracy, every status,
distortion, degenerate inputs and the domain type."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from triangulation import (
    PointStatus,
    TriangulatedPoints,
    TriangulationSettings,
    correct_matches,
    fundamental_from_pose,
    sampson_distance,
    triangulate_pair,
)
from vio_core.camera import Camera
from vio_core.errors import InputError, SettingsError, ShapeError
from vio_core.geometry import invert_transform, make_transform, transform_points

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
SETTINGS = TriangulationSettings()


def _pose(rotvec, t_w_ref) -> np.ndarray:
    """T_ref_cur for a current camera at the origin and a reference camera at ``t_w_ref``."""
    T_w_ref = make_transform(Rotation.from_rotvec(rotvec).as_matrix(), t_w_ref)
    return invert_transform(T_w_ref)


T_REF_CUR = _pose([0.02, -0.05, 0.01], [-0.8, 0.1, -0.3])


def _project_unguarded(points_c, cam=CAM):
    """Pinhole projection without the z > 0 guard (for points behind the camera)."""
    return np.column_stack([cam.fx * points_c[:, 0] / points_c[:, 2] + cam.cx,
                            cam.fy * points_c[:, 1] / points_c[:, 2] + cam.cy])


def _scene(n=300, seed=0, z=(3.0, 25.0)):
    rng = np.random.default_rng(seed)
    depth = rng.uniform(*z, n)
    uv = np.column_stack([rng.uniform(20, 620, n), rng.uniform(20, 460, n)])
    pts = CAM.backproject(uv, depth)
    return pts


def _observe(pts, T_ref_cur=T_REF_CUR, cam_cur=CAM, cam_ref=CAM):
    return _project_unguarded(pts, cam_cur), _project_unguarded(transform_points(T_ref_cur, pts), cam_ref)


def test_exact_geometry_is_recovered():
    pts = _scene()
    uc, ur = _observe(pts)
    res = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR, SETTINGS)
    assert isinstance(res, TriangulatedPoints) and len(res) == len(pts)
    assert np.all(res.valid)
    np.testing.assert_allclose(res.depth, pts[:, 2], rtol=1e-6)
    np.testing.assert_allclose(res.points_cur, pts, rtol=1e-6, atol=1e-6)
    assert np.max(res.sampson_px) < 1e-6 and np.max(res.reprojection_px) < 1e-6
    np.testing.assert_array_equal(res.uv, uc)
    np.testing.assert_array_equal(res.confidence, np.ones(len(pts)))
    # triangulation angle equals the angle at the point between the two camera centres
    c_ref = -T_REF_CUR[:3, :3].T @ T_REF_CUR[:3, 3]
    v1, v2 = -pts, c_ref - pts
    cosang = np.sum(v1 * v2, 1) / np.linalg.norm(v1, axis=1) / np.linalg.norm(v2, axis=1)
    np.testing.assert_allclose(res.angle_deg, np.degrees(np.arccos(cosang)), atol=1e-6)


def test_noisy_pixels_give_small_depth_error():
    # 0.5 px noise, f = 500 px, angles >= ~1.7 deg: expected relative error ~1 %
    pts = _scene(n=500, seed=1, z=(3.0, 20.0))
    uc, ur = _observe(pts)
    rng = np.random.default_rng(2)
    res = triangulate_pair(uc + rng.normal(0, 0.5, uc.shape), ur + rng.normal(0, 0.5, ur.shape),
                           CAM, CAM, T_REF_CUR, SETTINGS)
    assert res.valid.mean() > 0.95
    rel = np.abs(res.depth[res.valid] / pts[res.valid, 2] - 1.0)
    assert np.median(rel) < 0.02
    # errors are consistent with the predicted uncertainty (pixel_sigma_px = 1 > 0.5 px)
    assert np.mean(np.abs(res.depth - pts[:, 2])[res.valid] < 2.0 * res.sigma_depth[res.valid]) > 0.95


def test_distorted_camera_gives_the_same_depths():
    cam_d = Camera(640, 480, 500.0, 500.0, 320.0, 240.0, dist=(-0.28, 0.09, 1e-3, -5e-4, -0.01))
    pts = _scene(seed=3)
    uc, ur = _observe(pts)
    raw_c, raw_r = cam_d.distort_points(uc), cam_d.distort_points(ur)
    assert np.max(np.linalg.norm(raw_c - uc, axis=1)) > 20  # distortion is not negligible
    res = triangulate_pair(raw_c, raw_r, cam_d, cam_d, T_REF_CUR, SETTINGS)
    assert np.all(res.valid)
    np.testing.assert_allclose(res.depth, pts[:, 2], rtol=1e-6)
    np.testing.assert_array_equal(res.uv, raw_c)  # raw pixels are kept for disparity sampling
    # ignoring the distortion breaks the geometry
    wrong = triangulate_pair(raw_c, raw_r, CAM, CAM, T_REF_CUR, SETTINGS)
    assert np.mean(np.abs(wrong.depth / pts[:, 2] - 1) > 1e-3) > 0.5


def test_different_intrinsics_in_the_two_views():
    cam_ref = Camera(800, 600, 650.0, 640.0, 410.0, 290.0)
    pts = _scene(seed=4)
    uc, ur = _observe(pts, cam_ref=cam_ref)
    res = triangulate_pair(uc, ur, CAM, cam_ref, T_REF_CUR, SETTINGS)
    assert np.all(res.valid)
    np.testing.assert_allclose(res.depth, pts[:, 2], rtol=1e-6)


def test_every_status_is_reachable():
    rng = np.random.default_rng(5)
    T_ref_cur = _pose([0.0, 0.0, 0.0], [-0.8, 0.1, -0.3])  # no rotation: near points stay in front
    pts = _scene(n=40, seed=6, z=(4.0, 12.0))
    far = CAM.backproject(rng.uniform(100, 500, (5, 2)), np.full(5, 1000.0))  # angle ~0.05 deg
    behind = np.column_stack([rng.uniform(-1, 1, 5), rng.uniform(-1, 1, 5), np.full(5, -6.0)])
    near = CAM.backproject(rng.uniform(300, 340, (5, 2)), np.full(5, 0.05))  # closer than min_depth_m
    uc, ur = _observe(np.vstack([pts, far, behind, near]), T_ref_cur)
    # EPIPOLAR: move points 0..9 of the reference image 6 px across their epipolar line
    F = fundamental_from_pose(T_ref_cur, CAM.K, CAM.K)
    line = np.column_stack([uc, np.ones(len(uc))]) @ F.T
    normal = line[:, :2] / np.linalg.norm(line[:, :2], axis=1, keepdims=True)
    ur[:10] += 6.0 * normal[:10]

    res = triangulate_pair(uc, ur, CAM, CAM, T_ref_cur, SETTINGS)
    st = res.status
    assert np.all(st[:10] == PointStatus.EPIPOLAR)
    assert np.all(res.sampson_px[:10] > SETTINGS.max_sampson_px)
    assert np.all(st[10:40] == PointStatus.VALID)
    assert np.all(st[40:45] == PointStatus.LOW_PARALLAX)
    assert np.all(res.angle_deg[40:45] < SETTINGS.min_angle_deg)
    assert np.all(st[45:50] == PointStatus.BEHIND_CAMERA)
    assert np.all(res.depth[45:50] < 0)
    assert np.all(st[50:55] == PointStatus.DEPTH_RANGE)
    np.testing.assert_allclose(res.depth[50:55], 0.05, rtol=1e-6)
    assert res.status_counts() == {"valid": 30, "epipolar": 10, "behind_camera": 5, "reprojection": 0,
                                   "low_parallax": 5, "depth_range": 5}
    # REPROJECTION: with the epipolar check switched off, the moved points fail reprojection
    loose = TriangulationSettings(max_sampson_px=1e6)
    res2 = triangulate_pair(uc, ur, CAM, CAM, T_ref_cur, loose)
    assert np.all(res2.status[:10] == PointStatus.REPROJECTION)
    assert np.all(res2.reprojection_px[:10] > loose.max_reprojection_px)
    np.testing.assert_array_equal(res2.status[10:], res.status[10:])
    # documented order: the far group is LOW_PARALLAX before DEPTH_RANGE
    res3 = triangulate_pair(uc, ur, CAM, CAM, T_ref_cur, TriangulationSettings(max_depth_m=8.0))
    assert np.all(res3.status[40:45] == PointStatus.LOW_PARALLAX)
    mid = res3.status[10:40]
    assert np.all(mid[pts[10:40, 2] > 8.0] == PointStatus.DEPTH_RANGE)
    assert np.all(mid[pts[10:40, 2] <= 8.0] == PointStatus.VALID)


def test_degenerate_inputs_are_statuses_not_exceptions():
    empty = triangulate_pair(np.zeros((0, 2)), np.zeros((0, 2)), CAM, CAM, T_REF_CUR, SETTINGS)
    assert len(empty) == 0 and empty.points_cur.shape == (0, 3)
    assert sum(empty.status_counts().values()) == 0
    # zero baseline (pure rotation): everything LOW_PARALLAX, nothing valid
    pts = _scene(n=50, seed=7)
    T_rot = _pose([0.05, 0.02, -0.03], [0.0, 0.0, 0.0])
    uc, ur = _observe(pts, T_rot)
    res = triangulate_pair(uc, ur, CAM, CAM, T_rot, SETTINGS)
    assert len(res) == 50 and np.all(res.status == PointStatus.LOW_PARALLAX)
    assert res.status_counts()["low_parallax"] == 50 and not res.valid.any()
    np.testing.assert_allclose(res.angle_deg, 0.0, atol=1e-6)  # rays are parallel
    # tiny (non-zero) baseline: no exception, no valid point, no NaN in valid depths
    T_tiny = _pose([0.05, 0.02, -0.03], [1e-7, 0.0, 0.0])
    res = triangulate_pair(uc, ur, CAM, CAM, T_tiny, SETTINGS)
    assert not res.valid.any()
    # a point exactly at the epipole of a forward motion has no parallax
    T_fwd = _pose([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    uc2, ur2 = _observe(np.array([[0.0, 0.0, 10.0], [2.0, 1.0, 10.0]]), T_fwd)
    res = triangulate_pair(uc2, ur2, CAM, CAM, T_fwd, SETTINGS)
    assert res.status[0] == PointStatus.LOW_PARALLAX and res.status[1] == PointStatus.VALID
    assert np.all(np.isfinite(res.depth[res.valid])) and np.all(np.isfinite(res.sigma_depth[res.valid]))


def test_domain_type_helpers_and_confidence():
    pts = _scene(n=20, seed=8)
    uc, ur = _observe(pts)
    ur[:4, 1] += 10.0
    conf = np.linspace(0.0, 1.0, 20)
    res = triangulate_pair(uc, ur, CAM, CAM, T_REF_CUR, SETTINGS, confidence=conf)
    np.testing.assert_array_equal(res.confidence, conf)
    assert res.status.dtype == np.uint8
    good = res.subset(res.valid)
    assert len(good) == res.valid.sum() == 16 and np.all(good.valid)
    np.testing.assert_array_equal(good.depth, res.depth[res.valid])
    picked = res.subset(np.array([3, 5]))
    assert len(picked) == 2 and picked.status[0] == PointStatus.EPIPOLAR and picked.valid[1]
    assert res.status_counts()["valid"] == 16 and res.status_counts()["epipolar"] == 4
    with pytest.raises(InputError):
        res.subset(np.ones(3, bool))


def test_bad_inputs_raise():
    uc = np.zeros((5, 2))
    with pytest.raises(ShapeError):
        triangulate_pair(uc, np.zeros((4, 2)), CAM, CAM, T_REF_CUR, SETTINGS)
    with pytest.raises(ShapeError):
        triangulate_pair(np.full((5, 2), np.nan), uc, CAM, CAM, T_REF_CUR, SETTINGS)
    with pytest.raises(ShapeError):
        triangulate_pair(uc, uc, CAM, CAM, np.eye(3), SETTINGS)
    with pytest.raises(ShapeError):
        triangulate_pair(uc, uc, CAM, CAM, T_REF_CUR, SETTINGS, pose_covariance=np.eye(5))
    with pytest.raises(ShapeError):
        triangulate_pair(uc, uc, CAM, CAM, T_REF_CUR, SETTINGS, confidence=np.ones(4))
    for bad in (dict(max_sampson_px=0), dict(min_angle_deg=-1), dict(min_depth_m=5, max_depth_m=1),
                dict(pixel_sigma_px=-0.1)):
        with pytest.raises(SettingsError):
            TriangulationSettings(**bad)


def test_optimal_correction_is_minimal_and_exact():
    pts = _scene(n=6, seed=9)
    uc, ur = _observe(pts)
    rng = np.random.default_rng(10)
    uc, ur = uc + rng.normal(0, 1.0, uc.shape), ur + rng.normal(0, 1.0, ur.shape)
    F = fundamental_from_pose(T_REF_CUR, CAM.K, CAM.K)
    cc, cr = correct_matches(F, uc, ur)
    assert np.max(sampson_distance(F, cc, cr)) < 1e-8
    cost = np.sum((cc - uc) ** 2, 1) + np.sum((cr - ur) ** 2, 1)
    # first order, the squared Sampson distance is the minimal squared displacement
    np.testing.assert_allclose(cost, sampson_distance(F, uc, ur) ** 2, rtol=1e-2)
    for i in range(len(uc)):  # brute-force constrained minimisation agrees
        def f(p, i=i):
            return np.sum((p[:2] - uc[i]) ** 2) + np.sum((p[2:] - ur[i]) ** 2)

        con = {"type": "eq", "fun": lambda p: 1e3 * (np.r_[p[2:], 1.0] @ F @ np.r_[p[:2], 1.0])}
        opt = minimize(f, np.r_[uc[i], ur[i]], constraints=[con], method="SLSQP",
                       options={"ftol": 1e-14, "maxiter": 200})
        assert cost[i] <= opt.fun * (1 + 1e-6) + 1e-12


def test_cross_and_homogeneous_equal_numpy_bit_for_bit():
    from triangulation.epipolar import _cross, _homogeneous

    rng = np.random.default_rng(1)
    for n in (0, 1, 5, 4097):
        a = rng.normal(size=(n, 3)) * 10 ** rng.uniform(-8, 8, (n, 1))
        b = rng.normal(size=(n, 3))
        assert np.array_equal(_cross(a, b), np.cross(a, b))
        uv = rng.normal(size=(n, 2))
        for x in (uv, uv.astype(np.float32)):
            h = _homogeneous(x)
            assert h.dtype == np.float64 and h.flags.c_contiguous
            assert np.array_equal(h, np.column_stack([x, np.ones(n)]))
