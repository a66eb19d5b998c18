"""One dynamic initialisation attempt as a pure function of picklable inputs.

:func:`attempt_dynamic` reconstructs the candidate keyframes up to scale (:mod:`.sfm`: two
bundle adjustments) and aligns them with the IMU (:mod:`.alignment`): gyroscope bias, metric
scale, gravity, velocities; it gives each keyframe's :class:`~.imu_factors.KeyframeState`,
or why the attempt is refused. Its input (:class:`DynamicAttempt`) carries only what that
needs -- the keyframes' keypoints and matches (no descriptors), their times and cameras, the
IMU samples over their span and the settings -- so that it can run in the landmark window's
worker process (:meth:`~vio_depth.landmarks.ProcessWindow.submit_call`) while the caller
goes on with the next frames (:mod:`.init_remote`); :class:`~.initializer.Initializer` runs
it in the frame otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vio_core.checks import check_array

from ..frame import ImuData
from ..poses import preintegration_params
from .alignment import Alignment, align
from .imu_factors import KeyframeState
from .settings import VioSettings
from .sfm import SfmKeyframe, SfmResult, reconstruct


@dataclass(frozen=True)
class DynamicAttempt:
    """What one dynamic initialisation attempt reads (picklable).

    Attributes:
        keyframes: the candidates, oldest first (keypoints (N, 2) raw pixels, matches with
            earlier candidates of the tuple only).
        times: (K,) seconds of the keyframes.
        imu: the IMU samples over the keyframes' span (at least; ``ImuData.window``).
        settings: the odometry's settings (``init``, ``imu``, the start's prior sigmas).
    """

    keyframes: tuple[SfmKeyframe, ...]
    times: np.ndarray
    imu: ImuData
    settings: VioSettings

    def __post_init__(self):
        check_array("times", self.times, (len(self.keyframes),))


@dataclass(frozen=True)
class DynamicOutcome:
    """The attempt's outcome: ``ok`` with the keyframes' ``states``, or the ``reason`` it was
    refused; ``sfm`` / ``alignment``: the intermediate results (``alignment`` None when the
    reconstruction failed)."""

    ok: bool
    reason: str = ""
    states: tuple[KeyframeState, ...] = ()
    sfm: SfmResult | None = None
    alignment: Alignment | None = None


def attempt_dynamic(attempt: DynamicAttempt, params=None) -> DynamicOutcome:
    """Reconstruct and align the attempt's keyframes (module docstring).

    Args:
        attempt: :class:`DynamicAttempt`.
        params: gtsam preintegration parameters of ``attempt.imu`` (built from it and the
            settings when None, e.g. in a worker process).
    """
    s = attempt.settings
    imu = attempt.imu
    if params is None:
        params = preintegration_params(imu, s.imu)
    sfm = reconstruct(list(attempt.keyframes), min_landmarks=s.init.min_landmarks,
                      max_residual_px=s.init.max_residual_px)
    if not sfm.ok:
        return DynamicOutcome(False, f"dynamic initialisation refused: {sfm.reason}", sfm=sfm)
    times = np.asarray(attempt.times, float)
    al = align(sfm.T_c0_c, times, imu, params, s.init, s.imu.max_sample_gap_s)
    if not al.ok:
        return DynamicOutcome(False, f"dynamic initialisation refused: {al.reason}", sfm=sfm, alignment=al)
    states = []
    for k, t in enumerate(times):
        states.append(KeyframeState(float(t), al.T_w_c[k] @ imu.T_c_i, al.velocity_w[k], np.zeros(3), al.gyro_bias,
                                    tilt_sigma=max(al.tilt_sigma, s.tilt_sigma_rad), yaw_sigma=s.gauge_yaw_sigma_rad,
                                    position_sigma=s.gauge_sigma_m,
                                    velocity_sigma=max(0.05, 3 * al.scale_sigma * float(
                                        np.linalg.norm(al.velocity_w[k]))),
                                    accel_bias_sigma=s.imu.accel_bias_prior_sigma,
                                    gyro_bias_sigma=max(s.imu.gyro_bias_prior_sigma * 0.5, 1e-3)))
    return DynamicOutcome(True, states=tuple(states), sfm=sfm, alignment=al)
