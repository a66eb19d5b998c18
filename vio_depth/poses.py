"""Pose sources: where the metric relative pose between a frame and its keyframe comes from.

The pipeline only needs the relative pose ``T_kf_cur`` (current camera to keyframe
camera, metres) and, when known, its uncertainty. ``gt`` reads the sequence's poses;
``imu`` (see :mod:`vio_depth.imu`) preintegrates IMU samples between the two frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vio_core.errors import lookup
from vio_core.geometry import relative_transform
from .types import Frame


@dataclass(frozen=True)
class RelativePose:
    """Relative pose of the current camera in the keyframe camera.

    Attributes:
        T_kf_cur: (4, 4) current-camera-to-keyframe-camera transform, metres.
        covariance: (6, 6) covariance of the tangent-space error (rotation rad first,
            then translation m) of ``T_kf_cur``, or None when unknown (ground truth).
        ok: False when no pose is available; ``reason`` says why.
    """

    T_kf_cur: np.ndarray | None
    covariance: np.ndarray | None = None
    ok: bool = True
    reason: str = ""


class PoseSource(Protocol):
    name: str

    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        """Relative pose between ``keyframe`` (earlier) and ``current``."""


class GroundTruthPoses:
    """Relative poses from the sequence's metric camera-to-world poses."""

    name = "gt"

    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        if keyframe.T_w_c is None or current.T_w_c is None:
            return RelativePose(None, ok=False, reason="sequence has no pose for this frame")
        return RelativePose(relative_transform(keyframe.T_w_c, current.T_w_c))


def _create_imu(sequence):
    from .imu import ImuPoseSource  # gtsam is imported only for --poses imu

    return ImuPoseSource.for_sequence(sequence)


_POSE_SOURCES = {"gt": lambda sequence: GroundTruthPoses(), "imu": _create_imu}


def available_pose_sources() -> list[str]:
    return sorted(_POSE_SOURCES)


def create_pose_source(name: str, sequence) -> PoseSource:
    """Pose source ``name`` ("gt" or "imu") for ``sequence``.

    Raises:
        UnknownNameError: unknown name (lists the valid ones).
        InputError: e.g. "imu" on a sequence without IMU samples.
    """
    return lookup("pose source", name, _POSE_SOURCES)(sequence)
