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
``gyro``           the camera's rotation between two frames from the gyroscope (KLT prediction)
=================  ===========================================================================

The presets (``--poses``: :data:`vio_depth.pipeline.POSE_PRESETS`) and the choice of a source
from its settings (:func:`vio_depth.pipeline.build_pose_stage`) live two layers up, above the
visual-inertial odometry (:mod:`vio_depth.vio`) whose settings they name too.
"""

from .base import FramePose, PoseSource, PoseStatus, RelativePose, TrackingPoseSource
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
from .gyro import camera_rotation, gyro_rotation
from .imu import ImuPoseSource
from .imu_state import ImuPoseSettings, NavEstimate
from .preintegration import (
    ImuIntegration,
    WindowFit,
    fit_window,
    gravity_aligned_rotation,
    import_gtsam,
    integrate_interval,
    preintegrate,
    preintegration_params,
)
from .static_init import StaticInit, StaticInitSettings, detect_still_interval, static_initialisation
from .timeline import PoseTimeline
from .uncertainty import POSE_UNCERTAINTY_PRESETS, FrameTwist, PoseUncertainty, camera_twist

__all__ = [
    "POSE_UNCERTAINTY_PRESETS",
    "camera_rotation",
    "gyro_rotation",
    "FrameTwist",
    "PoseUncertainty",
    "camera_twist",
    "FramePose",
    "PoseStatus",
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
    "PoseSource",
    "RelativePose",
    "StaticInit",
    "StaticInitSettings",
    "TrackingPoseSource",
    "WindowFit",
    "calibrated_poses",
    "calibration_pairs",
    "detect_still_interval",
    "estimate_pose_calibration",
    "fit_window",
    "gravity_aligned_rotation",
    "integrate_interval",
    "preintegrate",
    "preintegration_params",
    "import_gtsam",
    "solve_pose_calibration",
    "static_initialisation",
]
