"""Pose stage: the metric relative pose between a keyframe and a later frame, with its uncertainty.

=================  ===========================================================================
module             job
=================  ===========================================================================
``base``           :class:`RelativePose`, the :class:`PoseSource` protocol
``groundtruth``    ``gt``: the sequence's own poses
``imu_state``      :class:`ImuPoseSettings`, :class:`NavEstimate`
``preintegration`` gtsam IMU preintegration, the bias/velocity window fit
``imu``            ``imu``: :class:`ImuPoseSource`
``registry``       :data:`POSE_PRESETS`, :func:`create_pose_source`
=================  ===========================================================================
"""

from .base import PoseSource, RelativePose
from .groundtruth import GroundTruthPoses, GroundTruthPoseSettings
from .imu import ImuPoseSource
from .imu_state import ImuPoseSettings, NavEstimate
from .preintegration import ImuIntegration, WindowFit, fit_window, integrate_interval, preintegration_params
from .registry import POSE_PRESETS, PoseSettings, create_pose_source

__all__ = [
    "POSE_PRESETS",
    "GroundTruthPoseSettings",
    "GroundTruthPoses",
    "ImuIntegration",
    "ImuPoseSettings",
    "ImuPoseSource",
    "NavEstimate",
    "PoseSettings",
    "PoseSource",
    "RelativePose",
    "WindowFit",
    "create_pose_source",
    "fit_window",
    "integrate_interval",
    "preintegration_params",
]
