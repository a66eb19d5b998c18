"""Static initialisation from the IMU alone: still interval, roll/pitch, gyroscope bias.

A robot that starts still gives, over the still interval:

* **roll and pitch** from the mean specific force ``a`` (it opposes gravity:
  ``R_w_i a ~ -g_w``); the yaw is unobservable (set to the minimal rotation, see
  :func:`vio_depth.poses.preintegration.gravity_aligned_rotation`);
* **gyroscope bias** = the mean angular rate (the true rate is zero), with standard error
  ``std / sqrt(n_eff)``;
* **velocity** zero.

**Accelerometer bias is not observable** from a still interval: ``a = R_i_w (-g_w) + b_a``
has five unknowns (roll, pitch, three bias components) in three equations. The two
components perpendicular to gravity are absorbed into roll/pitch -- a horizontal bias
``b`` tilts the estimate by ``atan(b / |g|)`` (0.1 m/s^2 -> 0.58 deg) -- and the component
along gravity is only as known as the local gravity magnitude
(:attr:`StaticInit.accel_bias_along_gravity` is ``|a| - |g|``, a diagnostic, not an
estimate to subtract). The bias must come from motion later (the window fit of
:mod:`vio_depth.poses.imu`, or a visual-inertial estimator).

Stillness is detected on the *low-frequency* IMU signal, because a vehicle at rest may
vibrate strongly (EuRoC V1_01 on the ground with its rotors running: per-sample
accelerometer standard deviation 0.1-1.3 m/s^2, 5-50x the datasheet white noise): from
the first sample on, consecutive windows of ``window_s`` are still while their mean
specific force and mean angular rate stay within ``accel_tolerance`` /
``gyro_tolerance`` of the means of all still windows before them, their mean angular
rate stays below ``max_gyro_rate`` (a plausible gyroscope bias) and their mean specific
force within ``max_gravity_mismatch`` of ``|g|``. Limits: uniform motion (constant
velocity, or a constant acceleration with no rotation) looks exactly like rest to an IMU;
the tests here only bound it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vio_core.checks import check_array
from vio_core.errors import SettingsError
from vio_core.settings import require_positive

from ..frame import ImuData
from .preintegration import gravity_aligned_rotation


@dataclass(frozen=True)
class StaticInitSettings:
    """Settings of :func:`static_initialisation`.

    Attributes:
        window_s: seconds per window of the stillness test.
        accel_tolerance: m/s^2, largest deviation of a window's mean specific force (vector)
            from the still mean so far (0.25 m/s^2 sustained for one 0.5 s window moves
            the body 3 cm).
        gyro_tolerance: rad/s, same for the mean angular rate.
        max_gyro_rate: rad/s, largest mean angular rate of a still window (the gyroscope
            bias bound: MEMS biases are at most a few degrees per second).
        max_gravity_mismatch: m/s^2, largest ``| |mean specific force| - |g| |`` of a still window.
        min_still_s: shortest still interval accepted, seconds.
        start_s: seconds after the first IMU sample where the search starts.
    """

    window_s: float = 0.5
    accel_tolerance: float = 0.25
    gyro_tolerance: float = 0.02
    max_gyro_rate: float = 0.15
    max_gravity_mismatch: float = 0.5
    min_still_s: float = 1.0
    start_s: float = 0.0

    def __post_init__(self):
        require_positive(self, "window_s", "accel_tolerance", "gyro_tolerance", "max_gyro_rate", "max_gravity_mismatch",
                         "min_still_s", finite=False)
        if self.start_s < 0:
            raise SettingsError(f"StaticInitSettings.start_s must be >= 0, got {self.start_s}")


@dataclass(frozen=True)
class StaticInit:
    """Result of a static initialisation, or why it failed.

    Attributes:
        ok: True when a still interval of at least ``min_still_s`` was found.
        reason: why not (empty when ok).
        t_start, t_end: the still interval, seconds.
        R_w_i: (3, 3) IMU-to-world rotation: roll/pitch from gravity, yaw arbitrary.
        gyro_bias: (3,) rad/s. gyro_bias_sigma: (3,) rad/s standard error of the mean.
        mean_accel: (3,) m/s^2 mean specific force over the interval.
        accel_bias_along_gravity: ``|mean_accel| - |g|`` m/s^2 (diagnostic; see the module
            docstring: the accelerometer bias is not observable).
        tilt_sigma_rad: 1-sigma of roll/pitch from the accelerometer noise of the mean
            alone; a horizontal accelerometer bias ``b`` adds ``b / |g|`` on top.
    """

    ok: bool
    reason: str = ""
    t_start: float = float("nan")
    t_end: float = float("nan")
    R_w_i: np.ndarray | None = None
    gyro_bias: np.ndarray | None = None
    gyro_bias_sigma: np.ndarray | None = None
    mean_accel: np.ndarray | None = None
    accel_bias_along_gravity: float = float("nan")
    tilt_sigma_rad: float = float("nan")

    @property
    def duration_s(self) -> float:
        return self.t_end - self.t_start


def detect_still_interval(imu: ImuData, settings: StaticInitSettings = StaticInitSettings()) -> tuple[float, float]:
    """``(t_start, t_end)`` seconds of the still interval at the start (``t_end == t_start`` if none).

    Windows are consecutive, ``settings.window_s`` long, from ``imu.t[0] + start_s``; the
    interval ends at the end of the last still window before the first moving one.
    """
    t = imu.t
    t0 = float(t[0]) + settings.start_s
    edges = np.arange(t0, float(t[-1]) + 1e-9, settings.window_s)
    idx = np.searchsorted(t, edges)
    # window means of the specific force and the angular rate (vectorised via cumulative sums)
    cs_a = np.concatenate([np.zeros((1, 3)), np.cumsum(imu.accel, axis=0)])
    cs_g = np.concatenate([np.zeros((1, 3)), np.cumsum(imu.gyro, axis=0)])
    counts = np.diff(idx)
    good = counts > 0
    mean_a = np.full((len(counts), 3), np.nan)
    mean_g = np.full((len(counts), 3), np.nan)
    mean_a[good] = (cs_a[idx[1:]] - cs_a[idx[:-1]])[good] / counts[good, None]
    mean_g[good] = (cs_g[idx[1:]] - cs_g[idx[:-1]])[good] / counts[good, None]
    g = float(np.linalg.norm(imu.gravity_w))
    plausible = good.copy()
    plausible[good] = ((np.linalg.norm(mean_g[good], axis=1) <= settings.max_gyro_rate)
                       & (np.abs(np.linalg.norm(mean_a[good], axis=1) - g) <= settings.max_gravity_mismatch))
    sum_a, sum_g, n = np.zeros(3), np.zeros(3), 0
    for k in range(len(counts)):  # sequential: each window is tested against the still mean so far
        if not plausible[k]:
            break
        if n and (np.linalg.norm(mean_a[k] - sum_a / n) > settings.accel_tolerance
                  or np.linalg.norm(mean_g[k] - sum_g / n) > settings.gyro_tolerance):
            break
        sum_a, sum_g, n = sum_a + mean_a[k], sum_g + mean_g[k], n + 1
    return t0, float(edges[n]) if n else t0


def static_initialisation(imu: ImuData, settings: StaticInitSettings = StaticInitSettings()) -> StaticInit:
    """Still interval, roll/pitch and gyroscope bias from the start of ``imu`` (module docstring)."""
    t_start, t_end = detect_still_interval(imu, settings)
    if t_end - t_start < settings.min_still_s:
        return StaticInit(False, f"no still interval of {settings.min_still_s} s at the start "
                                 f"(still for {t_end - t_start:.2f} s from {t_start:.3f} s)", t_start, t_end)
    sel = (imu.t >= t_start) & (imu.t < t_end)
    acc, gyr = imu.accel[sel], imu.gyro[sel]
    mean_a = acc.mean(axis=0)
    g = check_array("gravity_w", imu.gravity_w, (3,), finite=True)
    n_win = max(int(round((t_end - t_start) / settings.window_s)), 2)
    # standard errors from the scatter of the window means (vibration is not white at 200 Hz)
    win = np.array_split(np.arange(len(acc)), n_win)
    gyro_sigma = np.std([gyr[w].mean(0) for w in win], axis=0, ddof=1) / np.sqrt(n_win)
    acc_sigma = np.std([acc[w].mean(0) for w in win], axis=0, ddof=1) / np.sqrt(n_win)
    return StaticInit(
        True, "", t_start, t_end, gravity_aligned_rotation(mean_a, g), gyr.mean(axis=0), gyro_sigma, mean_a,
        float(np.linalg.norm(mean_a) - np.linalg.norm(g)), float(np.linalg.norm(acc_sigma) / np.linalg.norm(g)))


__all__ = ["StaticInit", "StaticInitSettings", "detect_still_interval", "static_initialisation"]
