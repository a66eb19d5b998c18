"""Pose stage: the metric relative pose between a keyframe and a later frame, with its uncertainty.

=================  ===========================================================================
module             job
=================  ===========================================================================
``base``           :class:`RelativePose`, the :class:`PoseSource` protocol
``groundtruth``    ``gt``: the sequence's own poses
``imu_state``      :class:`ImuPoseSettings`, :class:`NavEstimate`
``preintegration`` gtsam IMU preintegration, the bias/velocity window fit
``imu``            ``imu``: :class:`ImuPoseSource`
``static_init``    still interval, roll/pitch and gyroscope bias from the IMU alone
``uncertainty``    :class:`PoseUncertainty`: what a sequence's poses get wrong, presets by kind
``timeline``       :class:`PoseTimeline`: a sequence's poses as a function of time (splines)
``calibration``    time offset and camera-to-body transform of the poses, from the images
``vio_settings``   :class:`VioSettings` of the ``vio`` source (:mod:`vio_depth.vio`)
``registry``       :data:`POSE_PRESETS`, :func:`create_pose_source`, :func:`register_pose_source`
=================  ===========================================================================
"""

from .base import FramePose, PoseSource, RelativePose, TrackingPoseSource
from .calibration import (
    PoseCalibration,
    PoseCalibrationSettings,
    calibrated_poses,
    calibration_pairs,
    estimate_pose_calibration,
    solve_pose_calibration,
)
from .calibration_solver import PairMatches
from .groundtruth import GroundTruthPoses, GroundTruthPoseSettings
from .imu import ImuPoseSource
from .imu_state import ImuPoseSettings, NavEstimate
from .preintegration import (
    ImuIntegration,
    WindowFit,
    adjoint,
    fit_window,
    gravity_aligned_rotation,
    integrate_interval,
    preintegrate,
    preintegration_params,
)
from .registry import POSE_PRESETS, PoseSettings, create_pose_source, register_pose_source
from .static_init import StaticInit, StaticInitSettings, detect_still_interval, static_initialisation
from .timeline import PoseTimeline
from .uncertainty import POSE_UNCERTAINTY_PRESETS, FrameTwist, PoseUncertainty, camera_twist
from .vio_settings import RestSettings, VioInitSettings, VioSettings

__all__ = [
    "POSE_PRESETS",
    "POSE_UNCERTAINTY_PRESETS",
    "FrameTwist",
    "PoseUncertainty",
    "camera_twist",
    "FramePose",
    "GroundTruthPoseSettings",
    "GroundTruthPoses",
    "ImuIntegration",
    "ImuPoseSettings",
    "ImuPoseSource",
    "NavEstimate",
    "PairMatches",
    "PoseCalibration",
    "PoseCalibrationSettings",
    "PoseTimeline",
    "PoseSettings",
    "PoseSource",
    "RelativePose",
    "StaticInit",
    "StaticInitSettings",
    "TrackingPoseSource",
    "RestSettings",
    "VioInitSettings",
    "VioSettings",
    "WindowFit",
    "adjoint",
    "calibrated_poses",
    "calibration_pairs",
    "create_pose_source",
    "detect_still_interval",
    "estimate_pose_calibration",
    "fit_window",
    "gravity_aligned_rotation",
    "integrate_interval",
    "preintegrate",
    "preintegration_params",
    "register_pose_source",
    "solve_pose_calibration",
    "static_initialisation",
]
