"""The odometry's result for one frame: its state (:class:`VioStatus`, described in
:mod:`.estimator`) and pose (:class:`VioFrame`)."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from .initializer import InitKind


class VioStatus(str, enum.Enum):
    """The odometry's state at a frame (:mod:`.estimator`'s docstring)."""

    INITIALISING = "initialising"
    CONVERGING = "converging"
    TRACKING = "tracking"
    STILL = "still"
    IMU_ONLY = "imu_only"
    LOST = "lost"


@dataclass(frozen=True)
class VioFrame:
    """The odometry's result for one frame.

    Attributes:
        frame_id: the frame. status: :class:`VioStatus`. reason: why no pose / what is special.
        T_w_c: (4, 4) camera-to-world, metres (None without a pose).
        covariance: (6, 6) relative to the newest keyframe (right perturbation), or None.
        keyframe: the frame became a keyframe of the window.
        landmarks: landmarks the frame's pose was refined against.
        velocity_w: (3,) m/s IMU velocity of the newest keyframe. accel_bias / gyro_bias: its biases.
        initialised: the :class:`InitKind` on the frame that completed an initialisation, else None.
    """

    frame_id: int
    status: VioStatus
    reason: str = ""
    T_w_c: np.ndarray | None = None
    covariance: np.ndarray | None = None
    keyframe: bool = False
    landmarks: int = 0
    velocity_w: np.ndarray | None = None
    accel_bias: np.ndarray | None = None
    gyro_bias: np.ndarray | None = None
    initialised: InitKind | None = None

    @property
    def ok(self) -> bool:
        return self.T_w_c is not None
