"""The iSAM2 window (``LandmarkSettings.solver = "isam2"``, :mod:`vio_depth.landmarks.isam`)
against the batch window on synthetic scenes of known truth: the same keyframe poses and
landmark depths within stated tolerances, memory bounded by the window over many keyframes
(iSAM2's factor slots are reused), marginalisation with motion factors, unknown solver names."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.errors import UnknownNameError
from vio_depth.landmarks import LANDMARK_SOLVERS, LandmarkEstimator, LandmarkSettings, pose_prior_preset
from vio_depth.vio import VioSettings

from .synthetic import IdMatcher, make_scene
from .test_window import NOISY, _errors, _Odometry, _run

pytest.importorskip("gtsam")


def _pose_differences(wa, wb):
    """(max translation difference m, max rotation difference deg) between two windows' keyframe poses."""
    assert wa.keyframe_ids == wb.keyframe_ids
    dt, dr = [], []
    for f in wa.keyframe_ids:
        a, b = wa.pose(f), wb.pose(f)
        dt.append(np.linalg.norm(a[:3, 3] - b[:3, 3]))
        dr.append(np.degrees(np.linalg.norm(Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).as_rotvec())))
    return max(dt), max(dr)


def test_isam2_agrees_with_batch_under_noisy_poses():
    """Noisy pose priors (0.1 deg, 5 mm): the iSAM2 window's keyframe poses are within 1 mm and
    0.02 deg of the batch window's, its points within 0.3 % in depth (median), and as accurate
    against the truth (median depth error within 10 % of the batch's); covariances agree too."""
    scene = make_scene(n_frames=24, n_points=300, step_m=0.06, prior_rot_deg=0.1, prior_trans_m=0.005,
                       pixel_sigma=0.5, seed=3)
    batch, out_b = _run(scene, LandmarkSettings(pose_prior=NOISY, window_keyframes=8))
    isam, out_i = _run(scene, LandmarkSettings(pose_prior=NOISY, window_keyframes=8, solver="isam2"))
    assert isam.window._graph.updates > 0 and isam.window._graph.rebuilds == 0
    dt, dr = _pose_differences(batch.window, isam.window)
    assert dt < 1e-3 and dr < 0.02, (dt, dr)
    rel = []
    for (pb, _, _), (pi, _, _) in zip(out_b, out_i):
        common, ib, ii = np.intersect1d(pb.landmark_ids, pi.landmark_ids, return_indices=True)
        rel.append(np.abs(pi.depth[ii] / pb.depth[ib] - 1))
    rel = np.concatenate(rel)
    assert len(rel) > 3000 and np.median(rel) < 3e-3, (len(rel), np.median(rel))
    e_b, e_i = _errors(out_b, first=6), _errors(out_i, first=6)
    assert abs(len(e_i) - len(e_b)) <= 0.02 * len(e_b)
    assert np.median(e_i) < 1.1 * np.median(e_b), (np.median(e_i), np.median(e_b))
    f = batch.window.keyframe_ids[-1]
    sb, si = np.sqrt(np.diag(batch.window.pose_covariance(f))), np.sqrt(np.diag(isam.window.pose_covariance(f)))
    assert np.allclose(si, sb, rtol=0.2), (si, sb)


def test_isam2_memory_is_bounded_by_the_window():
    """Many keyframes through a 4-keyframe window: iSAM2 holds a bounded number of factors
    (removed factors' slots are reused) and only the window's poses and landmarks."""
    scene = make_scene(n_frames=40, n_points=250, step_m=0.05, seed=6)
    settings = LandmarkSettings(pose_prior=pose_prior_preset("exact"), window_keyframes=4, max_keyframe_gap=1,
                                solver="isam2")
    est = LandmarkEstimator(settings, IdMatcher())
    held, slots, poses = [], [], []
    for k in range(len(scene.T_w_c)):
        est.process(k, k / 30.0, scene.camera, scene.T_prior[k], scene.features[k])
        g = est.window._graph
        held.append(g.factor_slots())
        slots.append(g._isam.getFactorsUnsafe().size())
        keys = [gtsam_chr(key) for key in g._isam.calculateEstimate().keys()]
        poses.append(keys.count("x"))
    assert est.window.keyframe_ids == list(range(36, 40))
    assert max(poses) == 5  # the window's 4, and the marginalised one until the next update removes it
    assert max(held[20:]) <= 1.3 * max(held[4:12]), held
    assert max(slots[20:]) <= 1.5 * max(slots[4:12]), slots  # (not growing with the keyframes)
    assert est.window.factor_count() <= max(
        LandmarkEstimator(LandmarkSettings(pose_prior=pose_prior_preset("exact"), window_keyframes=4,
                                           max_keyframe_gap=1), IdMatcher()).window.factor_count(), 8)


def gtsam_chr(key: int) -> str:
    import gtsam

    return chr(gtsam.Symbol(key).chr())


def test_isam2_marginalisation_with_motion_factors_matches_batch():
    """A motion factor source (first keyframe anchored, between-factors after it): the oldest
    keyframes are marginalised into the same linear factors; poses agree with the batch
    window's within 2 mm and the newest keyframe has not drifted."""
    scene = make_scene(n_frames=20, n_points=250, step_m=0.06, seed=11)
    results = {}
    for solver in LANDMARK_SOLVERS:
        settings = LandmarkSettings(pose_prior=pose_prior_preset("imu"), window_keyframes=4, max_keyframe_gap=1,
                                    solver=solver)
        est = LandmarkEstimator(settings, IdMatcher(), motion_factors=_Odometry(scene))
        for k in range(len(scene.T_w_c)):
            est.process(k, k / 30.0, scene.camera, scene.T_w_c[k], scene.features[k])
        results[solver] = est.window
    w = results["isam2"]
    dt, dr = _pose_differences(results["batch"], w)
    assert dt < 2e-3 and dr < 0.05, (dt, dr)
    drift = np.linalg.norm(w.pose(w.keyframe_ids[-1])[:3, 3] - scene.T_w_c[w.keyframe_ids[-1]][:3, 3])
    assert drift < 0.01


def test_unknown_solver_name_raises():
    with pytest.raises(UnknownNameError, match="batch, isam2"):
        LandmarkSettings(solver="isam")
    with pytest.raises(ValueError):
        LandmarkSettings(solver="")
    assert LandmarkSettings().solver == "isam2"  # the points window's default since 2026-12-06
    assert VioSettings().window.solver == "batch"  # the odometry's window keeps batch
