"""The pose stage's contract: a :class:`PoseSource` gives the metric :class:`RelativePose`
between a keyframe and a later frame.

The pipeline only needs the relative pose ``T_kf_cur`` (current camera to keyframe
camera, metres) and, when known, its uncertainty. Sources: :mod:`.groundtruth` (the
sequence's poses) and :mod:`.imu` (IMU preintegration);
:func:`vio_depth.pipeline.build_pose_stage` builds the one its settings name.

A :class:`TrackingPoseSource` (visual-inertial odometry, :mod:`vio_depth.vio`) estimates
the poses itself from the frames: the pipeline hands it every frame, in order, with the
frame's features (extracted once, by the pipeline's matcher) before it asks for relative
poses, and records the source's own :class:`FramePose` of the frame.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from matchers import Features, Matcher

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
    """Gives relative poses between frames of one camera (``name``: its ``--poses`` name)."""

    name: str

    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        """Relative pose between ``keyframe`` (earlier) and ``current``."""


class PoseStatus(str, enum.Enum):
    """A tracking pose source's state at a frame (:attr:`FramePose.status`).

    The odometry's own states (``vio_depth.vio.VioStatus``, same strings), and two of the
    pose source's: ``retroactive`` (a frame seen again, posed after it was first processed)
    and ``unknown`` (a frame the source never tracked).
    """

    INITIALISING = "initialising"
    CONVERGING = "converging"
    TRACKING = "tracking"
    STILL = "still"
    IMU_ONLY = "imu_only"
    LOST = "lost"
    RETROACTIVE = "retroactive"
    UNKNOWN = "unknown"


@dataclass(frozen=True)
class FramePose:
    """A tracking pose source's own estimate of one frame.

    Attributes:
        T_w_c: (4, 4) camera-to-world pose in the source's world frame (metres), or None.
        covariance: (6, 6) covariance of ``T_w_c`` relative to the source's newest keyframe
            (right perturbation, rotation rad first, then metres), or None.
        ok: True when ``T_w_c`` is trusted; otherwise the frame has no pose.
        status: :class:`PoseStatus`, the source's state at this frame, or None when it
            states none (its string value is accepted and converted; an unknown one raises
            ValueError).
        reason: why there is no pose, or what is special about it ("" when nothing).
    """

    T_w_c: np.ndarray | None
    covariance: np.ndarray | None = None
    ok: bool = True
    status: PoseStatus | None = None
    reason: str = ""

    def __post_init__(self):
        object.__setattr__(self, "status", None if self.status in (None, "") else PoseStatus(self.status))


@runtime_checkable
class TrackingPoseSource(Protocol):
    """A pose source that estimates the poses from the frames (and the IMU) itself.

    ``matcher`` is the matcher whose features it needs: the pipeline extracts every
    frame's features with it (once) and calls :meth:`track` for each frame in order,
    before any :meth:`relative` call involving that frame.
    """

    name: str
    matcher: Matcher

    def track(self, frame: Frame, features: Features) -> FramePose:
        """Process the next frame; its pose (or why it has none)."""

    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        """Relative pose between two tracked frames (either order in time)."""

    def world_pose(self, frame: Frame) -> np.ndarray | None:
        """(4, 4) the source's latest camera-to-world pose of a tracked frame, or None."""

    def finish(self) -> None:
        """The sequence ended (an offline run, before its backward pass): settle what is still
        pending, so that :meth:`relative` and :meth:`world_pose` give the final poses."""
