"""``gt``: relative poses from the sequence's own metric camera-to-world poses, with the
covariance its kind of poses states (:mod:`.uncertainty`)."""

from __future__ import annotations

from dataclasses import dataclass

from vio_core.geometry import relative_transform

from ..frame import Frame
from .base import RelativePose
from .uncertainty import POSE_UNCERTAINTY_PRESETS, FrameTwist, PoseUncertainty


@dataclass(frozen=True)
class GroundTruthPoseSettings:
    """Settings of :class:`GroundTruthPoses`.

    Attributes:
        uncertainty: the stated error of the sequence's poses, or None (the default): the
            :data:`~vio_depth.poses.uncertainty.POSE_UNCERTAINTY_PRESETS` entry of the
            sequence's kind of poses (``Sequence.pose_kind``; ``exact`` for rendered
            samples, which then carry no covariance).
    """

    uncertainty: PoseUncertainty | None = None

    def resolved(self, pose_kind: str) -> PoseUncertainty:
        """The uncertainty to use for a sequence whose poses are of kind ``pose_kind``."""
        return self.uncertainty if self.uncertainty is not None else POSE_UNCERTAINTY_PRESETS[pose_kind]


class GroundTruthPoses:
    """Relative poses from the sequence's metric camera-to-world poses (``Frame.T_w_c``).

    Args:
        settings: :class:`GroundTruthPoseSettings`.
        pose_kind: the sequence's kind of poses (``Sequence.pose_kind``), used when the
            settings name no uncertainty; ``exact`` when unknown (no covariance).
    """

    name = "gt"

    def __init__(self, settings: GroundTruthPoseSettings = GroundTruthPoseSettings(), pose_kind: str = "exact"):
        self.settings = settings
        self.pose_kind = pose_kind
        #: the stated uncertainty of the relative poses (exact: covariance None)
        self.uncertainty = settings.resolved(pose_kind)
        self._twists = FrameTwist()

    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        if keyframe.T_w_c is None or current.T_w_c is None:
            return RelativePose(None, ok=False, reason="sequence has no pose for this frame")
        T = relative_transform(keyframe.T_w_c, current.T_w_c)
        if self.uncertainty.exact:
            return RelativePose(T)
        for f in (keyframe, current):
            self._twists.observe(f.index, f.timestamp, f.T_w_c)
        cov = self.uncertainty.relative_covariance(T, self._twists.twist(keyframe.index),
                                                   self._twists.twist(current.index))
        return RelativePose(T, cov)
