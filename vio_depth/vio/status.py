"""The odometry's result for one frame: its state (:class:`VioStatus`, described in
:mod:`.estimator`) and pose (:class:`VioFrame`)."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from .imu_factors import KeyframeState
from .initializer import InitKind
from .settings import VioSettings


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


def implausible(state: KeyframeState, settings: VioSettings) -> str:
    """Why a keyframe's ``state`` is implausible ("" when it is fine): not finite, or its speed or
    biases beyond ``max_speed_m_s``, ``max_accel_bias``, ``max_gyro_bias``."""
    s = settings
    if not np.all(np.isfinite(state.T_w_i)):
        return "the estimate is not finite"
    speed = float(np.linalg.norm(state.velocity_w))
    if not speed <= s.max_speed_m_s:
        return f"estimated speed {speed:.1f} m/s (> {s.max_speed_m_s})"
    if not np.linalg.norm(state.accel_bias) <= s.max_accel_bias:
        return f"estimated accelerometer bias {np.linalg.norm(state.accel_bias):.2f} m/s^2 (> {s.max_accel_bias})"
    if not np.linalg.norm(state.gyro_bias) <= s.max_gyro_bias:
        return f"estimated gyroscope bias {np.linalg.norm(state.gyro_bias):.3f} rad/s (> {s.max_gyro_bias})"
    return ""
