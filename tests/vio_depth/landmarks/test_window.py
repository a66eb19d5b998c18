"""The gtsam landmark window on synthetic scenes of known truth: refinement beats two-view
triangulation under noisy poses, the priors hold the scale, marginalisation bounds memory,
wrong matches are rejected, the per-frame query refines a frame's pose, and the motion
factor hook (for IMU) replaces the pose priors."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from triangulation import TriangulationSettings, triangulate_pair
from vio_core.errors import InputError, SettingsError, UnknownNameError
from vio_core.geometry import invert_transform, make_transform
from vio_depth.landmarks import (
    FrameMatches,
    LandmarkEstimator,
    LandmarkSettings,
    LandmarkWindow,
    MotionFactors,
    PosePriorSettings,
    pose_prior_preset,
)
from vio_depth.landmarks.motion import pose_noise

from .synthetic import IdMatcher, make_scene

gtsam = pytest.importorskip("gtsam")

#: per-pose prior errors of the noisy scenes (1-sigma per axis) and the matching settings:
#: independent absolute errors make consecutive relative errors sqrt(2) larger
ROT_DEG, TRANS_M = 0.1, 0.005
NOISY = PosePriorSettings(ROT_DEG, TRANS_M, ROT_DEG * 1.5, TRANS_M * 1.5, 0.0)


def _run(scene, settings, frames=None):
    """Process a scene; per frame (points, true depth of each point, result)."""
    est = LandmarkEstimator(settings, IdMatcher())
    out = []
    for k in range(len(scene.T_w_c) if frames is None else frames):
        res = est.process(k, k / 30.0, scene.camera, scene.T_prior[k], scene.features[k])
        p = res.points
        ids = scene.ids[k][p.keypoint_index]
        out.append((p, scene.depth_of(k, ids), res))
    return est, out


def _errors(out, first=0):
    e = [np.abs(p.depth - z) / z for p, z, _ in out[first:] if len(p)]
    return np.concatenate(e) if e else np.zeros(0)


def _two_view_errors(scene, gap=3):
    errs = []
    for k in range(gap, len(scene.T_w_c)):
        a, b = scene.features[k], scene.features[k - gap]
        m = IdMatcher().match(a, b)
        T = invert_transform(scene.T_prior[k - gap]) @ scene.T_prior[k]
        pts = triangulate_pair(a.keypoints[m.idx_a], b.keypoints[m.idx_b], scene.camera, scene.camera, T,
                               TriangulationSettings())
        ok = pts.valid
        z = scene.depth_of(k, scene.ids[k][m.idx_a[ok]])
        errs.append(np.abs(pts.depth[ok] - z) / z)
    return np.concatenate(errs)


@pytest.mark.parametrize("gate", [False, True])
def test_refined_landmarks_beat_two_view_under_noisy_poses(gate):
    scene = make_scene(n_frames=16, n_points=300, step_m=0.06, prior_rot_deg=ROT_DEG, prior_trans_m=TRANS_M,
                       pixel_sigma=0.5, seed=3)
    _, out = _run(scene, LandmarkSettings(pose_prior=NOISY, gate_extended_tracks=gate))
    lm = _errors(out, first=6)
    two = _two_view_errors(scene)
    assert len(lm) > 1000
    assert np.median(lm) < 0.6 * np.median(two), (np.median(lm), np.median(two))
    assert np.median(lm) < 0.02


def test_depth_sigma_is_honest():
    """Normalised squared depth errors of the returned points are near or below 1 (the
    sigma is not overconfident), and refinement shrinks the keyframe pose errors."""
    scene = make_scene(n_frames=16, n_points=300, step_m=0.06, prior_rot_deg=ROT_DEG, prior_trans_m=TRANS_M,
                       pixel_sigma=0.5, seed=4)
    # keyframe_relative_sigma 0.15 (the default until 2026-12-04): this short scene needs its
    # keyframes to test the refinement; at the default 0.12 it gets too few for the 0.5 x bound
    est, out = _run(scene, LandmarkSettings(pose_prior=NOISY, keyframe_relative_sigma=0.15))
    z2 = np.concatenate([((p.depth - z) / p.sigma_depth) ** 2 for p, z, _ in out[6:] if len(p)])
    assert 0.1 < np.median(z2) < 1.5
    w = est.window
    rot_err = [np.degrees(np.linalg.norm(Rotation.from_matrix(
        w.pose(f)[:3, :3].T @ scene.T_w_c[f][:3, :3]).as_rotvec())) for f in w.keyframe_ids]
    prior_err = [np.degrees(np.linalg.norm(Rotation.from_matrix(
        scene.T_prior[f][:3, :3].T @ scene.T_w_c[f][:3, :3]).as_rotvec())) for f in w.keyframe_ids]
    assert np.median(rot_err) < 0.5 * np.median(prior_err)


def test_scale_is_held_by_the_priors():
    """Scaling the world (priors' translations) by 1.1 with the same images scales every
    depth by 1.1: the images cannot move the metric scale."""
    scene = make_scene(n_frames=14, n_points=250, step_m=0.06, prior_rot_deg=ROT_DEG, prior_trans_m=TRANS_M,
                       seed=5)
    _, out1 = _run(scene, LandmarkSettings(pose_prior=NOISY))
    scaled = replace(scene, T_prior=scene.T_prior.copy())
    scaled.T_prior[:, :3, 3] *= 1.1
    _, out2 = _run(scaled, LandmarkSettings(pose_prior=replace(NOISY, absolute_translation_m=TRANS_M * 1.1,
                                                                relative_translation_m=TRANS_M * 1.65)))
    ratios = []
    for (p1, _, _), (p2, _, _) in zip(out1, out2):
        common, i1, i2 = np.intersect1d(p1.landmark_ids, p2.landmark_ids, return_indices=True)
        if len(common):
            ratios.append(p2.depth[i2] / p1.depth[i1])
    r = np.concatenate(ratios)
    assert len(r) > 500
    assert abs(np.median(r) - 1.1) < 0.005


def test_marginalisation_keeps_memory_bounded():
    scene = make_scene(n_frames=24, n_points=250, step_m=0.05, seed=6)
    settings = LandmarkSettings(pose_prior=pose_prior_preset("exact"), window_keyframes=4, max_keyframe_gap=1)
    est = LandmarkEstimator(settings, IdMatcher())
    sizes = []
    for k in range(len(scene.T_w_c)):
        est.process(k, k / 30.0, scene.camera, scene.T_prior[k], scene.features[k])
        w = est.window
        sizes.append((len(w.keyframe_ids), len(w.tracks.frames), w.factor_count(), w.estimate.size()))
        assert w.tracks.frames == w.keyframe_ids
    assert max(s[0] for s in sizes) == 4
    assert sizes[-1][2] <= sizes[8][2]  # non-visual factors do not accumulate
    assert max(s[3] for s in sizes[8:]) <= 4  # poses only (landmarks are rebuilt per update)
    assert est.window.keyframe_ids == list(range(20, 24))


@pytest.mark.parametrize("gate", [False, True])
def test_wrong_matches_are_rejected(gate):
    """5 % of the keypoints are wrong matches (moved by 20-60 px): almost none reach the
    returned points, and the points are as accurate as without them -- also when the tracks a
    keyframe extends are gated against their points instead of triangulated again."""
    settings = LandmarkSettings(pose_prior=pose_prior_preset("exact"), gate_extended_tracks=gate)
    scene = make_scene(n_frames=14, n_points=300, step_m=0.06, outlier_fraction=0.05, seed=7)
    _, out = _run(scene, settings)
    used = np.concatenate([scene.outlier[k][p.keypoint_index] for k, (p, _, _) in enumerate(out) if len(p)])
    assert used.mean() < 0.005
    _, clean = _run(make_scene(n_frames=14, n_points=300, step_m=0.06, seed=7), settings)
    assert np.percentile(_errors(out), 95) < 1.2 * np.percentile(_errors(clean), 95)


def test_query_refines_a_non_keyframe_pose():
    scene = make_scene(n_frames=12, n_points=300, step_m=0.06, seed=8)
    settings = LandmarkSettings(pose_prior=pose_prior_preset("mocap"))
    est, _ = _run(scene, settings, frames=10)
    w = est.window
    k = 11  # not processed: a frame with a rotated prior (0.3 deg)
    T_prior = scene.T_w_c[k] @ make_transform(Rotation.from_rotvec(np.radians([0.3, -0.2, 0.0])).as_matrix(), np.zeros(3))
    feats = scene.features[k]
    matches = [FrameMatches.from_matches(f, IdMatcher().match(feats, est._features[f])) for f in w.keyframe_ids[-3:]]
    p = w.query(scene.camera, T_prior, feats.keypoints, matches)
    assert p.pose_refined and len(p) > 100
    err = np.degrees(np.linalg.norm(Rotation.from_matrix(p.T_w_c[:3, :3].T @ scene.T_w_c[k][:3, :3]).as_rotvec()))
    assert err < 0.25 * np.hypot(0.3, 0.2)
    z = scene.depth_of(k, scene.ids[k][p.keypoint_index])
    assert np.median(np.abs(p.depth - z) / z) < 0.02


class _Odometry:
    """A MotionFactorSource stand-in for IMU preintegration: the first keyframe anchored by
    its pose prior, then between-factors from the true relative poses (what a VIO would add
    between keyframes), kept through marginalisation."""

    provides_poses = False
    keep_marginals = True

    def __init__(self, scene):
        self.scene = scene

    def extra_keys(self, frame_id):
        return []

    def factors(self, previous, current, estimate, initial=None):
        from gtsam.symbol_shorthand import X

        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        T = self.scene.T_w_c
        f = current.frame_id
        if previous is None:
            p = pose_prior_preset("imu")
            graph.add(gtsam.PriorFactorPose3(X(f), gtsam.Pose3(current.T_w_c),
                                             pose_noise(np.radians(p.absolute_rotation_deg), p.absolute_translation_m)))
            values.insert(X(f), gtsam.Pose3(current.T_w_c))
        else:
            rel = invert_transform(T[previous.frame_id]) @ T[f]
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3] * 3 + [2e-3] * 3))
            graph.add(gtsam.BetweenFactorPose3(X(previous.frame_id), X(f), gtsam.Pose3(rel), noise))
            values.insert(X(f), gtsam.Pose3(estimate.atPose3(X(previous.frame_id)).matrix() @ rel))
        return MotionFactors(graph, values)

    def after_marginalisation(self, oldest, estimate):
        return gtsam.NonlinearFactorGraph()


def test_motion_factor_source_replaces_pose_priors():
    scene = make_scene(n_frames=14, n_points=250, step_m=0.06, seed=9)
    imu = pose_prior_preset("imu")
    with pytest.raises(InputError):
        LandmarkWindow(LandmarkSettings(pose_prior=imu))
    # keyframe_relative_sigma 0.15: at the default 0.12 the 14 frames (0.8 m) under the imu prior
    # never reach a second keyframe, and this test is about the motion factors, not the policy
    est = LandmarkEstimator(LandmarkSettings(pose_prior=imu, keyframe_relative_sigma=0.15), IdMatcher(),
                            motion_factors=_Odometry(scene))
    errs = []
    for k in range(len(scene.T_w_c)):
        res = est.process(k, k / 30.0, scene.camera, scene.T_w_c[k], scene.features[k])
        p = res.points
        if len(p):
            z = scene.depth_of(k, scene.ids[k][p.keypoint_index])
            errs.append(np.abs(p.depth - z) / z)
    assert np.median(np.concatenate(errs)) < 0.02


def test_stopping_on_a_small_error_decrease_keeps_the_converged_accuracy():
    """The default ``lm_min_error_decrease`` (0.5: an iteration that lowers the graph error by
    less is the last) stops the refinement about two iterations earlier than full convergence
    (asl_room, klt: 136 -> 75 iterations over 24 keyframes), with the same landmarks."""
    scene = make_scene(n_frames=16, n_points=300, step_m=0.06, prior_rot_deg=ROT_DEG, prior_trans_m=TRANS_M,
                       pixel_sigma=0.5, seed=3)
    early = LandmarkSettings(pose_prior=NOISY)
    assert early.lm_min_error_decrease == 0.5
    _, out_early = _run(scene, early)
    _, out_full = _run(scene, replace(early, lm_min_error_decrease=0.0))
    e_early, e_full = _errors(out_early, first=6), _errors(out_full, first=6)
    assert abs(len(e_early) - len(e_full)) <= 0.02 * len(e_full)
    assert np.median(e_early) == pytest.approx(np.median(e_full), rel=0.05)
    final = [r.update.lm_error_after for _, _, r in out_early if r.update is not None and r.update.ok]
    full = [r.update.lm_error_after for _, _, r in out_full if r.update is not None and r.update.ok]
    assert len(final) == len(full) > 3
    # each early stop is within a few error units of the converged minimum (errors are 0.5 chi2)
    assert np.all(np.asarray(final) <= np.asarray(full) + 5.0), (final, full)


def test_settings_are_checked():
    with pytest.raises(SettingsError):
        LandmarkSettings(window_keyframes=1)
    with pytest.raises(SettingsError):
        LandmarkSettings(lm_min_error_decrease=-1.0)
    with pytest.raises(SettingsError):
        PosePriorSettings(absolute_translation_m=0.0)
    with pytest.raises(UnknownNameError):
        pose_prior_preset("nonsense")


@pytest.mark.parametrize("turn_deg", [0.0, 1.5])
def test_frames_without_a_fresh_pair_still_get_metric_points(turn_deg):
    """After the camera stops (standing still, or turning in place), no pair has parallax,
    yet every such frame still sees the window's landmarks at accurate depths."""
    scene = make_scene(n_frames=12, n_points=300, step_m=0.06, seed=10, hold_frames=6, hold_rotation_deg=turn_deg)
    _, out = _run(scene, LandmarkSettings(pose_prior=pose_prior_preset("mocap")))
    for p, z, res in out[12:]:
        assert len(p) > 80
        assert np.median(np.abs(p.depth - z) / z) < 0.02


def test_marginalisation_with_motion_factors_keeps_the_chain():
    """With a motion factor source (no per-keyframe priors), the oldest keyframes are
    marginalised into linear factors: the window stays bounded and the poses anchored."""
    scene = make_scene(n_frames=20, n_points=250, step_m=0.06, seed=11)
    settings = LandmarkSettings(pose_prior=pose_prior_preset("imu"), window_keyframes=4, max_keyframe_gap=1)
    est = LandmarkEstimator(settings, IdMatcher(), motion_factors=_Odometry(scene))
    counts, errs = [], []
    for k in range(len(scene.T_w_c)):
        res = est.process(k, k / 30.0, scene.camera, scene.T_w_c[k], scene.features[k])
        counts.append(est.window.factor_count())
        p = res.points
        if len(p) and k >= 8:
            z = scene.depth_of(k, scene.ids[k][p.keypoint_index])
            errs.append(np.abs(p.depth - z) / z)
    w = est.window
    assert len(w.keyframe_ids) == 4 and max(counts[8:]) <= max(counts[:8]) + 2
    drift = np.linalg.norm(w.pose(w.keyframe_ids[-1])[:3, 3] - scene.T_w_c[w.keyframe_ids[-1]][:3, 3])
    assert drift < 0.01
    # as accurate as the same 4-keyframe window with exact priors on every keyframe
    _, ref = _run(scene, LandmarkSettings(pose_prior=pose_prior_preset("exact"), window_keyframes=4,
                                          max_keyframe_gap=1))
    assert np.median(np.concatenate(errs)) < 1.3 * np.median(_errors(ref, first=8))


@pytest.mark.parametrize("dist", [(-0.25, 0.08, 0.001, -0.0005), (-0.25, 0.08, 0.001, -0.0005, 0.02)])
def test_distorted_camera(dist):
    """Raw pixels of a distorted camera: Cal3DS2 in the graph (k1, k2, p1, p2), or ideal
    pixels when the model has more coefficients (k3)."""
    from vio_core.camera import Camera

    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0, dist)
    scene = make_scene(n_frames=12, n_points=300, step_m=0.06, seed=12, camera=cam,
                       prior_rot_deg=ROT_DEG, prior_trans_m=TRANS_M, pixel_sigma=0.5)
    _, out = _run(scene, LandmarkSettings(pose_prior=NOISY))
    assert np.median(_errors(out, first=5)) < 0.02
