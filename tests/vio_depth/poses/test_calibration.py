"""Pose-camera calibration (issue 20, item 4): a time offset and a camera-to-body transform
recovered from the epipolar geometry of many frame pairs, applied only when significant and
well constrained.

The scene (calibration_scene.py): 4000 random 3D points 2-7 m in front of a camera (no
rendering), projected with 0.5 px noise and 5 % wrong matches, 25 Hz frames, the camera
rotating fast about three axes (peaks of 130-160 deg/s) while moving ~0.3 m/s. The
sequence's poses are those of a body: ``T_w_b(t) = T_w_c(t - dt) T_b_c^-1``.
"""

import numpy as np
import pytest

from vio_core.errors import InputError, SettingsError
from vio_depth.frame import Frame
from vio_depth.poses import (
    PoseCalibration,
    PoseCalibrationSettings,
    PoseTimeline,
    calibrated_poses,
    calibration_pairs,
    estimate_pose_calibration,
    solve_pose_calibration,
)

from .calibration_scene import (
    CAM,
    RATE_HZ,
    TRUE_DT,
    TRUE_T_B_C,
    IdMatcher,
    camera_trajectory,
    rotation_error_deg,
    scene,
    synthetic_pairs,
)

def test_a_time_offset_and_camera_to_body_offset_are_recovered_and_applied():
    ts, T_w_c, T_w_b, points = scene()
    cal = solve_pose_calibration(synthetic_pairs(ts, T_w_c, points), PoseTimeline(ts, T_w_b))
    assert cal.estimated and cal.applied, cal.reason
    assert abs(cal.time_offset_s - TRUE_DT) < 0.002
    assert np.linalg.norm(cal.T_b_c[:3, 3] - TRUE_T_B_C[:3, 3]) < 0.005
    assert rotation_error_deg(cal.T_b_c, TRUE_T_B_C) < 0.2
    assert cal.time_offset_sigma_s < 0.002 and cal.rotation_sigma_deg < 0.2 and cal.translation_sigma_m < 0.005
    assert "significant" in cal.reason and cal.pairs >= 40 and cal.matches > 5000
    assert cal.residual_before_px > 3.0 and cal.residual_after_px < 0.6  # 0.5 px noise
    # the corrected poses are the camera's: the body poses interpolated at t + dt, times T_b_c
    corrected = calibrated_poses(PoseTimeline(ts, T_w_b), ts[10:50], cal)
    assert max(rotation_error_deg(a, b) for a, b in zip(corrected, T_w_c[10:50])) < 0.2
    assert np.max(np.linalg.norm(corrected[:, :3, 3] - T_w_c[10:50, :3, 3], axis=1)) < 0.005
    js = cal.to_json()
    assert js["applied"] and abs(js["time_offset_s"] - TRUE_DT) < 0.002 and np.shape(js["T_b_c"]) == (4, 4)


def test_poses_that_are_the_cameras_give_a_calibration_that_is_not_significant():
    ts, T_w_c, T_w_b, points = scene(dt=0.0, T_b_c=np.eye(4))
    cal = solve_pose_calibration(synthetic_pairs(ts, T_w_c, points), PoseTimeline(ts, T_w_b))
    assert cal.estimated and not cal.applied
    assert cal.reason.startswith("not significant"), cal.reason
    assert abs(cal.time_offset_s) < 0.001 and cal.translation_m < 0.004 and cal.rotation_deg < 0.1
    # not applied: the poses stay the sequence's
    np.testing.assert_allclose(calibrated_poses(PoseTimeline(ts, T_w_b), ts, cal), T_w_b, atol=1e-9)


def test_without_rotation_the_lever_arm_is_not_constrained_and_nothing_is_applied():
    ts, T_w_c, T_w_b, points = scene(rotation_amp_deg=(0.0, 0.0, 0.0))
    cal = solve_pose_calibration(synthetic_pairs(ts, T_w_c, points), PoseTimeline(ts, T_w_b))
    assert cal.estimated and not cal.applied
    assert cal.reason.startswith("not well constrained") and "translation sigma" in cal.reason, cal.reason
    assert cal.translation_sigma_m > 0.005


def test_too_few_pairs_is_a_reason_not_an_error():
    ts, T_w_c, T_w_b, points = scene()
    cal = solve_pose_calibration(synthetic_pairs(ts, T_w_c, points)[:3], PoseTimeline(ts, T_w_b))
    assert not cal.estimated and not cal.applied and "3 frame pairs" in cal.reason
    assert "not estimated" in cal.summary()


def test_estimate_from_frames_extracts_each_frame_once_and_matches_chosen_pairs():
    ts, T_w_c, T_w_b, points = scene()
    frames = [Frame(i, float(t), f"{i:04d}", CAM, T_w_b[i],
                    load_image=lambda i=i: np.full((2, 2, 3), i, np.uint8)) for i, t in enumerate(ts)]
    matcher = IdMatcher(T_w_c, points)
    cal = estimate_pose_calibration(frames, matcher)  # the defaults: 30 anchors, pairs 0.1, 0.2, 0.3 s later
    assert len(matcher.extracted) == len(set(matcher.extracted)) <= 60
    assert cal.applied, cal.reason
    assert abs(cal.time_offset_s - TRUE_DT) < 0.002
    assert np.linalg.norm(cal.T_b_c[:3, 3] - TRUE_T_B_C[:3, 3]) < 0.005
    assert rotation_error_deg(cal.T_b_c, TRUE_T_B_C) < 0.2 and cal.seconds > 0


def test_a_short_run_is_skipped_before_any_image_is_read():
    ts, T_w_c, T_w_b, points = scene(n=6)

    def unread():
        raise AssertionError("an image was read")

    frames = [Frame(i, float(t), f"{i:04d}", CAM, T_w_b[i], load_image=unread) for i, t in enumerate(ts)]
    cal = estimate_pose_calibration(frames, IdMatcher(T_w_c, points))
    assert not cal.estimated and "frame pairs that moved" in cal.reason and "(need 8)" in cal.reason


def test_calibration_pairs_spread_anchors_and_skip_pairs_that_did_not_move():
    ts = np.arange(100) / 30.0
    positions = np.zeros((100, 3))
    positions[50:, 0] = np.arange(50) * 0.01  # still for the first half
    pairs = calibration_pairs(ts, positions, PoseCalibrationSettings(anchors=10, pair_gaps_s=(0.1, 0.2)))
    assert pairs and all(i < j for i, j in pairs) and len(set(pairs)) == len(pairs)
    assert all(i >= 47 for i, _ in pairs)  # no baseline before frame 50
    assert {j - i for i, j in pairs} == {3, 6}


def test_timeline_passes_through_its_samples_and_follows_a_fast_rotation_between_them():
    ts = 1.0 + np.arange(30) / RATE_HZ
    T = camera_trajectory(ts)
    timeline = PoseTimeline(ts, T)
    np.testing.assert_allclose(timeline.at(ts), T, atol=1e-9)
    mid = ts[5:20] + 0.5 / RATE_HZ
    between = timeline.at(mid)
    truth = camera_trajectory(mid)
    assert max(rotation_error_deg(a, b) for a, b in zip(between, truth)) < 0.02  # cubic: slerp misses by ~0.1 deg
    # the first interval and 15 ms beyond the last sample: one-sided cubics, no end conditions assumed
    ends = np.array([ts[0] + 0.015, ts[-1] + 0.015])
    assert max(rotation_error_deg(a, b) for a, b in zip(timeline.at(ends), camera_trajectory(ends))) < 0.05
    assert timeline.at(float(ts[3])).shape == (4, 4)
    with pytest.raises(InputError, match="increase"):
        PoseTimeline(ts[::-1], T)


def test_settings_are_validated():
    with pytest.raises(SettingsError, match="max_rotation_sigma_deg"):
        PoseCalibrationSettings(max_rotation_sigma_deg=0.0)
    with pytest.raises(SettingsError, match="pair_gaps_s"):
        PoseCalibrationSettings(pair_gaps_s=())
    with pytest.raises(SettingsError, match="anchors"):
        PoseCalibrationSettings(anchors=0)
    skipped = PoseCalibration.skipped("exact poses")
    assert skipped.to_json()["reason"] == "exact poses" and skipped.to_json()["time_offset_sigma_s"] is None
