"""Tests of vio_depth/run/output_poses.py: the pose each pose source's run gives its outputs."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from vio_core.camera import Camera
from vio_core.geometry import make_transform
from vio_depth.frame import Frame
from vio_depth.poses import FramePose, GroundTruthPoses
from vio_depth.run import OutputPoses

CAM = Camera(32, 24, 30.0, 30.0, 15.5, 11.5)


def _T(x: float) -> np.ndarray:
    return make_transform(np.eye(3), [x, 0.0, 0.0])


def _frame(i: int, T=None) -> Frame:
    return Frame(i, 0.1 * i, f"{i:06d}", CAM, T, load_image=lambda: np.zeros((24, 32, 3), np.uint8),
                 velocity_w=np.ones(3))


class _Sequence:
    def __init__(self, poses):
        self.frames = [_frame(i, T) for i, T in enumerate(poses)]

    def __getitem__(self, i):
        return self.frames[i]


def _result(pair=None, points_T=None, frame_pose=None):
    return SimpleNamespace(points=SimpleNamespace(T_w_c=points_T, relative_pose=pair), frame_pose=frame_pose)


def _pipeline(source, tracker=None):
    return SimpleNamespace(pose_source=source, tracker=tracker)


def test_gt_outputs_see_the_sequence_poses_unchanged():
    seq = _Sequence([_T(1.0), _T(2.0)])
    poses = OutputPoses(seq, _pipeline(GroundTruthPoses()), 2)
    frame = seq[1]
    assert poses.output_frame(frame, _result(pair=(0, _T(5.0)))) is frame


def test_tracking_outputs_see_the_odometry_pose_never_the_sequence_pose():
    tracker = object()
    seq = _Sequence([_T(1.0), _T(2.0), _T(3.0)])
    poses = OutputPoses(seq, _pipeline(tracker, tracker), 3)
    initialising = poses.output_frame(seq[0], _result(frame_pose=FramePose(None, ok=False, status="initialising")))
    assert initialising.T_w_c is None and initialising.velocity_w is None
    tracked = poses.output_frame(seq[1], _result(pair=(0, _T(9.0)), frame_pose=FramePose(_T(0.5))))
    np.testing.assert_array_equal(tracked.T_w_c, _T(0.5))
    refined = poses.output_frame(seq[2], _result(points_T=_T(0.7), frame_pose=FramePose(_T(0.6))))
    np.testing.assert_array_equal(refined.T_w_c, _T(0.7))  # the pose the points stage used
    assert seq[1].T_w_c[0, 3] == 2.0  # the sequence's frames are untouched


def test_relative_outputs_chain_on_keyframe_anchors():
    relative = object()
    # no sequence poses: the first frame is the origin, later frames chain on the run's own poses
    seq = _Sequence([None, None, None])
    poses = OutputPoses(seq, _pipeline(relative), 3)
    assert poses.output_frame(seq[0], _result()).T_w_c is None
    np.testing.assert_allclose(poses.output_frame(seq[1], _result(pair=(0, _T(1.0)))).T_w_c, _T(1.0))
    np.testing.assert_allclose(poses.output_frame(seq[2], _result(pair=(1, _T(0.5)))).T_w_c, _T(1.5))
    # with sequence poses, the keyframe's sequence pose is the anchor (the IMU source's own start)
    seq = _Sequence([_T(10.0), None, _T(20.0)])
    poses = OutputPoses(seq, _pipeline(relative), 3)
    poses.output_frame(seq[0], _result())
    np.testing.assert_allclose(poses.output_frame(seq[1], _result(pair=(0, _T(1.0)))).T_w_c, _T(11.0))
    # not the frame's own sequence pose (20): the run's, from its keyframe
    np.testing.assert_allclose(poses.output_frame(seq[2], _result(pair=(1, _T(1.0)))).T_w_c, _T(12.0))
    # a sequence with poses on later frames only: no identity origin for an unposed first keyframe
    seq = _Sequence([None, None, _T(20.0)])
    poses = OutputPoses(seq, _pipeline(relative), 3)
    poses.output_frame(seq[0], _result())
    assert poses.output_frame(seq[1], _result(pair=(0, _T(1.0)))).T_w_c is None
