"""Settings of the IMU pose source and the navigation state it integrates from."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ImuPoseSettings:
    """Settings of :class:`ImuPoseSource`.

    Attributes:
        max_interval_s: longest keyframe-to-frame interval integrated, seconds.
        max_sample_gap_s: largest gap between IMU samples inside an interval (and
            between an interval end and the nearest sample), seconds. KITTI sync has
            ~0.11 s gaps.
        integration_sigma: gtsam integration noise (position from velocity), m/sqrt(Hz)-ish.
        given_velocity_sigma: 1-sigma (m/s, per axis) of a dataset-given velocity.
        assume_static_start: without any pose or velocity, start at rest with
            roll/pitch from the accelerometer (see the module docstring).
        static_window_s: seconds of accelerometer averaged for the static start.
        accel_bias: (3,) m/s^2 prior accelerometer bias (IMU frame), subtracted.
        gyro_bias: (3,) rad/s prior gyroscope bias (IMU frame), subtracted.
        bias_window_s: seconds of the sequence's *past* poses (up to and including the
            keyframe) used to estimate the biases and the keyframe velocity
            (:func:`fit_window`); 0 disables the fit.
        min_window_frames: fewest posed frames in that window for a fit.
        min_fit_imu_rate_hz: no fit below this IMU rate (KITTI sync: 10 Hz), where the
            integration error of a sample interval exceeds the bias signal.
        accel_bias_prior_sigma: m/s^2, 1-sigma of the accelerometer bias around
            ``accel_bias`` (regularises short windows).
        gyro_bias_prior_sigma: rad/s, same for the gyroscope.
        pose_sigma_m / pose_sigma_rad: 1-sigma noise of the sequence's poses in the fit.
    """

    max_interval_s: float = 5.0
    max_sample_gap_s: float = 0.25
    integration_sigma: float = 1.0e-4
    given_velocity_sigma: float = 0.05
    assume_static_start: bool = True
    static_window_s: float = 0.2
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_window_s: float = 2.0
    min_window_frames: int = 3
    min_fit_imu_rate_hz: float = 50.0
    accel_bias_prior_sigma: float = 0.1
    gyro_bias_prior_sigma: float = 0.01
    pose_sigma_m: float = 0.002
    pose_sigma_rad: float = 0.001


@dataclass(frozen=True)
class NavEstimate:
    """IMU navigation state at one time.

    Attributes:
        t: seconds.
        T_w_i: (4, 4) IMU-to-world pose, metres.
        velocity_w: (3,) m/s world-frame IMU velocity.
        velocity_cov: (3, 3) (m/s)^2 covariance of ``velocity_w``.
        pose_source: "sequence", "estimate" or "static" (where T_w_i came from).
        velocity_source: "dataset", "window_fit", "previous_interval", "estimate",
            "finite_difference" or "static".
        accel_bias: (3,) m/s^2 accelerometer bias used from this state on.
        gyro_bias: (3,) rad/s gyroscope bias used from this state on.
    """

    t: float
    T_w_i: np.ndarray
    velocity_w: np.ndarray
    velocity_cov: np.ndarray
    pose_source: str
    velocity_source: str
    accel_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
