"""Choosing a pose source by name: each preset is a settings object, the source is built from it.

Sources of an upper layer (the visual-inertial odometry of :mod:`vio_depth.vio`, which
needs the landmark window and the features) register their factory for their settings
type with :func:`register_pose_source` when their package is imported (``import vio_depth``
imports it), as the sequence loaders register their formats.
"""

from __future__ import annotations

from typing import Callable

from matchers import Matcher
from vio_core.errors import InputError
from vio_core.settings import Presets

from .base import PoseSource
from .groundtruth import GroundTruthPoses, GroundTruthPoseSettings
from .imu import ImuPoseSource
from .imu_state import ImuPoseSettings
from .vio_settings import VioSettings

#: pose-source presets: ``gt`` (the sequence's poses), ``imu`` (gtsam preintegration, the
#: covariance calibrated on EuRoC V1_01), ``imu_real_mav`` (``imu`` with the accelerometer
#: noise x10, for a real MEMS IMU on a vibrating vehicle; docs/benchmarks.md) and ``vio``
#: (visual-inertial odometry: no sequence pose is used; docs/vio.md)
POSE_PRESETS: Presets = Presets("pose source", {
    "gt": GroundTruthPoseSettings(),
    "imu": ImuPoseSettings(),
    "imu_real_mav": ImuPoseSettings(accel_noise_scale=10.0),
    "vio": VioSettings(),
}, default="gt", descriptions={
    "gt": "the sequence's own metric poses",
    "imu": "gtsam IMU preintegration between keyframes (its covariance enters the points' sigma)",
    "imu_real_mav": "imu with the accelerometer noise x10: a real MEMS IMU on a vibrating vehicle "
                    "(calibrated on EuRoC V1_01)",
    "vio": "visual-inertial odometry from the images and the IMU alone (sequence poses only evaluate)",
})

PoseSettings = GroundTruthPoseSettings | ImuPoseSettings | VioSettings

#: settings type -> factory ``(settings, sequence, matcher) -> PoseSource`` of upper-layer sources
_FACTORIES: dict[type, Callable[..., PoseSource]] = {}


def register_pose_source(settings_type: type, factory: Callable[..., PoseSource]) -> None:
    """Build sources for settings of ``settings_type`` with ``factory(settings, sequence, matcher)``."""
    _FACTORIES[settings_type] = factory


def create_pose_source(settings: PoseSettings | str, sequence=None, matcher: Matcher | None = None) -> PoseSource:
    """The pose source for ``settings`` (a settings object, or a preset name) and ``sequence``.

    Args:
        settings: settings object or preset name.
        sequence: the sequence (IMU samples), when the source needs one.
        matcher: the pipeline's matcher, for a source that tracks features (``vio``).

    Raises:
        UnknownNameError: unknown preset name (lists the valid ones).
        InputError: e.g. ``imu`` on a sequence without IMU samples.
    """
    if isinstance(settings, str):
        settings = POSE_PRESETS[settings]
    if isinstance(settings, ImuPoseSettings):
        return ImuPoseSource.for_sequence(sequence, settings)
    factory = _FACTORIES.get(type(settings))
    if factory is not None:
        return factory(settings, sequence, matcher)
    if isinstance(settings, VioSettings):
        raise InputError("the vio pose source is not available: import vio_depth (it registers vio_depth.vio)")
    return GroundTruthPoses(settings, "exact" if sequence is None else sequence.pose_kind)
