"""Settings of the IMU pose source and the navigation state it integrates from."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vio_core.errors import SettingsError
from vio_core.settings import require_positive


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
        pose_sigma_m / pose_sigma_rad: 1-sigma noise of the sequence's poses in the fit
            (and, with ``pose_noise_in_velocity``, in the two-pose velocities).
        accel_noise_scale / gyro_noise_scale: factors on the IMU's white-noise densities
            (``ImuData.accel_noise`` / ``gyro_noise``) wherever the covariance is computed
            (preintegration, bias fit); 1 = the sensor's datasheet / Kalibr values.
        bias_covariance: add the bias estimate's uncertainty (from the window fit, else the
            bias prior sigmas) to the pose covariance, through the preintegration's bias
            Jacobian (``gtsam`` ``predict`` H2).
        bias_scatter_window_s: seconds of past window fits whose scatter the fit's bias
            covariance is grown to (per bias component; 0 = the least-squares covariance only).
        pose_noise_in_velocity: add the sequence poses' noise (``2 velocity_pose_sigma_m^2
            / dt^2``) to the covariance of a two-pose velocity.
        velocity_pose_sigma_m: 1-sigma position jitter between consecutive sequence poses,
            metres (a motion-capture / batch ground truth: ~0.1 mm; on EuRoC V1_01 the
            two-pose velocities differ from a smoothed ground-truth velocity by 2.5-4 mm/s
            per axis at 20 Hz, i.e. ~0.1 mm).

    The defaults are the covariance calibrated on the real EuRoC V1_01 IMU stream
    (docs/benchmarks.md, "IMU propagation and covariance"); :meth:`uncalibrated` gives the
    covariance before that calibration (datasheet noise only, no bias or pose-noise terms).
    The pose preset ``imu_real_mav`` (:data:`vio_depth.pipeline.POSE_PRESETS`) adds
    ``accel_noise_scale = 10`` for a real MEMS IMU on a vibrating vehicle.

    Raises:
        SettingsError: a noise scale, sigma or window that is not positive (or negative).
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
    accel_noise_scale: float = 1.0
    gyro_noise_scale: float = 1.0
    bias_covariance: bool = True
    bias_scatter_window_s: float = 10.0
    pose_noise_in_velocity: bool = True
    velocity_pose_sigma_m: float = 1.0e-4

    def __post_init__(self):
        require_positive(self, "accel_noise_scale", "gyro_noise_scale", "pose_sigma_m", "pose_sigma_rad",
                         "accel_bias_prior_sigma", "gyro_bias_prior_sigma", "velocity_pose_sigma_m", finite=False)
        if not self.bias_scatter_window_s >= 0:
            raise SettingsError(f"ImuPoseSettings.bias_scatter_window_s must be >= 0, got {self.bias_scatter_window_s}")

    @classmethod
    def uncalibrated(cls, **overrides) -> "ImuPoseSettings":
        """The covariance before the calibration: datasheet noise, no bias or pose-noise terms."""
        base = dict(accel_noise_scale=1.0, gyro_noise_scale=1.0, bias_covariance=False, pose_noise_in_velocity=False)
        base.update(overrides)
        return cls(**base)


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
        bias_cov: (6, 6) covariance of (accel_bias m/s^2, gyro_bias rad/s) (zero: exact).
    """

    t: float
    T_w_i: np.ndarray
    velocity_w: np.ndarray
    velocity_cov: np.ndarray
    pose_source: str
    velocity_source: str
    accel_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias_cov: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
