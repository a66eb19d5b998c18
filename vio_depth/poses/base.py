"""The pose stage's contract: a :class:`PoseSource` gives the metric :class:`RelativePose`
between a keyframe and a later frame.

The pipeline only needs the relative pose ``T_kf_cur`` (current camera to keyframe
camera, metres) and, when known, its uncertainty. Sources: :mod:`.groundtruth` (the
sequence's poses) and :mod:`.imu` (IMU preintegration); :mod:`.registry` chooses by name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..frame import Frame


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
    """Gives relative poses between frames of one camera (``name``: its registry name)."""

    name: str

    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        """Relative pose between ``keyframe`` (earlier) and ``current``."""
