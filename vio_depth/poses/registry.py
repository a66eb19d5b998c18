"""Choosing a pose source by name: each preset is a settings object, the source is built from it."""

from __future__ import annotations

from vio_core.settings import Presets

from .base import PoseSource
from .groundtruth import GroundTruthPoses, GroundTruthPoseSettings
from .imu import ImuPoseSource
from .imu_state import ImuPoseSettings

#: pose-source presets: ``gt`` (the sequence's poses), ``imu`` (gtsam preintegration, the
#: covariance calibrated on EuRoC V1_01) and ``imu_real_mav`` (``imu`` with the accelerometer
#: noise x10, for a real MEMS IMU on a vibrating vehicle; docs/benchmarks.md)
POSE_PRESETS: Presets = Presets("pose source", {
    "gt": GroundTruthPoseSettings(),
    "imu": ImuPoseSettings(),
    "imu_real_mav": ImuPoseSettings(accel_noise_scale=10.0),
}, default="gt", descriptions={
    "gt": "the sequence's own metric poses",
    "imu": "gtsam IMU preintegration between keyframes (its covariance enters the points' sigma)",
    "imu_real_mav": "imu with the accelerometer noise x10: a real MEMS IMU on a vibrating vehicle "
                    "(calibrated on EuRoC V1_01)",
})

PoseSettings = GroundTruthPoseSettings | ImuPoseSettings


def create_pose_source(settings: PoseSettings | str, sequence=None) -> PoseSource:
    """The pose source for ``settings`` (a settings object, or a preset name) and ``sequence``.

    Raises:
        UnknownNameError: unknown preset name (lists the valid ones).
        InputError: e.g. ``imu`` on a sequence without IMU samples.
    """
    if isinstance(settings, str):
        settings = POSE_PRESETS[settings]
    if isinstance(settings, ImuPoseSettings):
        return ImuPoseSource.for_sequence(sequence, settings)
    return GroundTruthPoses(settings)
