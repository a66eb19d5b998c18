"""Pose sources: the ground-truth relative pose, missing poses as statuses (choosing one by name:
tests/vio_depth/pipeline/test_build.py)."""

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core import Camera, make_transform
from vio_depth.frame import Frame
from vio_depth.poses import GroundTruthPoses

CAM = Camera(8, 6, 10.0, 10.0, 3.5, 2.5)


def _frame(index, T_w_c):
    return Frame(index, 0.1 * index, f"{index:06d}", CAM, T_w_c, load_image=lambda: np.zeros((6, 8, 3), np.uint8))


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
