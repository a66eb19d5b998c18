"""Visual-inertial odometry: metric camera poses from the images and the IMU alone (``--poses vio``).

==================  ==========================================================================
module              job
==================  ==========================================================================
``imu_factors``     gtsam ``CombinedImuFactor`` between the landmark window's keyframes
``sfm``             up-to-scale structure from motion over the first keyframes
``alignment``       scale, gravity, velocities and gyroscope bias from the IMU (dynamic start)
``initializer``     static start (still IMU and images), else the dynamic start
``history``         the estimated poses; relative poses with their covariance
``rest``            the zero-velocity test (IMU chi-square and image disparity) of a tracked frame
``bridge``          the poses of the frames between two keyframes, bridged by the IMU
``estimator``       :class:`VioEstimator`: initialising, tracking, lost, re-initialising
``source``          :class:`VioPoseSource`, the pipeline's ``vio`` pose source
``settings``        :class:`VioSettings`, :class:`VioInitSettings`
==================  ==========================================================================

The preset ``vio`` of :data:`vio_depth.pipeline.POSE_PRESETS` is ``VioSettings()``;
:func:`vio_depth.pipeline.build_pose_stage` builds the source for it (an explicit call:
importing this package registers nothing). docs/vio.md says what it needs and where it fails.
"""

from .alignment import Alignment, align, estimate_gyro_bias
from .bridge import FrameBridges
from .dynamic_start import DynamicAttempt, DynamicOutcome, attempt_dynamic
from .estimator import VioEstimator, VioFrame, VioStatus
from .history import PoseHistory, PoseRecord
from .imu_factors import ImuFactors, KeyframeState
from .init_remote import RemoteInitializer
from .initializer import Candidate, Initializer, InitKind, InitResult
from .rest import (AnchorMotion, RestAnchor, RestDetector, RestTest, anchor_motion, gyro_rotation_sigma,
                   zero_velocity_chi2)
from .settings import RestSettings, VioInitSettings, VioSettings
from .sfm import SfmKeyframe, SfmResult, reconstruct
from .source import VioPoseSource

__all__ = [
    "Alignment",
    "AnchorMotion",
    "Candidate",
    "DynamicAttempt",
    "DynamicOutcome",
    "FrameBridges",
    "ImuFactors",
    "InitKind",
    "InitResult",
    "Initializer",
    "KeyframeState",
    "PoseHistory",
    "PoseRecord",
    "RemoteInitializer",
    "RestAnchor",
    "RestDetector",
    "RestSettings",
    "RestTest",
    "SfmKeyframe",
    "SfmResult",
    "VioEstimator",
    "VioFrame",
    "VioInitSettings",
    "VioPoseSource",
    "VioSettings",
    "VioStatus",
    "align",
    "anchor_motion",
    "attempt_dynamic",
    "estimate_gyro_bias",
    "gyro_rotation_sigma",
    "reconstruct",
    "zero_velocity_chi2",
]
