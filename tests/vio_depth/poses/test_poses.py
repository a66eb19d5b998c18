"""Pose sources: the ground-truth relative pose, missing poses as statuses, the registry."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core import Camera, InputError, UnknownNameError, make_transform
from vio_depth.frame import Frame
from vio_depth.poses import (
    POSE_PRESETS,
    GroundTruthPoses,
    GroundTruthPoseSettings,
    ImuPoseSettings,
    ImuPoseSource,
    create_pose_source,
)

CAM = Camera(8, 6, 10.0, 10.0, 3.5, 2.5)


def _frame(index, T_w_c):
    return Frame(index, 0.1 * index, f"{index:06d}", CAM, T_w_c, load_image=lambda: np.zeros((6, 8, 3), np.uint8))


class _NoImu:
    root = "/data/seq"
    imu = None
    imu_missing_reason = "the dataset has no gyroscope"


def test_ground_truth_relative_pose_maps_current_into_keyframe():
    T_w_kf = make_transform(Rotation.from_euler("xyz", [3, -10, 20], degrees=True).as_matrix(), [1.0, 2.0, 0.5])
    T_w_cur = make_transform(Rotation.from_euler("xyz", [0, 5, 25], degrees=True).as_matrix(), [1.4, 2.1, 0.2])
    rel = GroundTruthPoses().relative(_frame(0, T_w_kf), _frame(1, T_w_cur))
    assert rel.ok and rel.covariance is None  # taken as exact
    p_cur = np.array([0.3, -0.2, 4.0, 1.0])
    np.testing.assert_allclose(rel.T_kf_cur @ p_cur, np.linalg.inv(T_w_kf) @ T_w_cur @ p_cur, atol=1e-12)


def test_a_frame_without_pose_gives_a_status_not_an_exception():
    rel = GroundTruthPoses().relative(_frame(0, np.eye(4)), _frame(1, None))
    assert not rel.ok and rel.T_kf_cur is None and "no pose" in rel.reason


def test_registry_by_name_or_settings():
    assert set(POSE_PRESETS) == {"gt", "imu", "imu_real_mav", "vio"} and POSE_PRESETS.default == "gt"
    assert isinstance(create_pose_source("gt"), GroundTruthPoses)
    assert isinstance(create_pose_source(GroundTruthPoseSettings()), GroundTruthPoses)
    with pytest.raises(UnknownNameError, match="gt, imu, imu_real_mav, vio"):
        create_pose_source("gps")
    with pytest.raises(InputError, match="no IMU.*no gyroscope.*--poses gt"):
        create_pose_source(ImuPoseSettings(), _NoImu())
    assert isinstance(POSE_PRESETS["imu"], ImuPoseSettings) and ImuPoseSource.name == "imu"
