"""``gt``: relative poses from the sequence's own metric camera-to-world poses."""

from __future__ import annotations

from dataclasses import dataclass

from vio_core.geometry import relative_transform

from ..frame import Frame
from .base import RelativePose


@dataclass(frozen=True)
class GroundTruthPoseSettings:
    """Settings of :class:`GroundTruthPoses` (none yet: the poses are taken as exact)."""


class GroundTruthPoses:
    """Relative poses from the sequence's metric camera-to-world poses (``Frame.T_w_c``)."""

    name = "gt"

    def __init__(self, settings: GroundTruthPoseSettings = GroundTruthPoseSettings()):
        self.settings = settings

    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        if keyframe.T_w_c is None or current.T_w_c is None:
            return RelativePose(None, ok=False, reason="sequence has no pose for this frame")
        return RelativePose(relative_transform(keyframe.T_w_c, current.T_w_c))
