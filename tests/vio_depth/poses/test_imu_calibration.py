"""The calibrated covariance of --poses imu: the bias and pose-noise terms against Monte Carlo
and closed forms, the bias-scatter growth, and the settings / presets."""

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import SettingsError, UnknownNameError
from vio_core.geometry import make_transform
from vio_depth.evaluation.imu_propagation import FrameList, ground_truth_frames
from vio_depth.frame import ImuData
from vio_depth.pipeline import POSE_PRESETS
from vio_depth.poses import (
    ImuPoseSettings,
    ImuPoseSource,
    NavEstimate,
    WindowFit,
    integrate_interval,
    preintegration_params,
)

G = 9.81


# --------------------------------------------------------------------------- covariance terms
def _turning_imu(duration=1.2, rate=200.0):
    t = np.arange(0.0, duration, 1 / rate)
    gyro = np.tile([0.2, -0.1, 0.5], (len(t), 1))
    accel = np.tile([0.8, 0.3, G], (len(t), 1))
    return ImuData(t, gyro, accel, np.eye(4), gyro_noise=1e-9, accel_noise=1e-9, gyro_bias_walk=1e-12,
                   accel_bias_walk=1e-12)


def test_bias_covariance_term_matches_monte_carlo():
    """Biases wrong by draws from N(0, S): the scatter of the predicted pose matches the
    covariance term H_b S H_b^T (white noise made negligible)."""
    gtsam = pytest.importorskip("gtsam")
    imu = _turning_imu()
    settings = ImuPoseSettings(integration_sigma=1e-9)
    params = preintegration_params(imu, settings)
    S = np.diag([0.05**2] * 3 + [0.003**2] * 3)
    start = NavEstimate(0.0, np.eye(4), np.array([1.0, 0.0, 0.0]), np.zeros((3, 3)), "sequence", "x",
                        bias_cov=S)
    nominal, _ = integrate_interval(imu, start, 1.0, params, settings)
    rng = np.random.default_rng(5)
    xis = []
    for _ in range(300):
        d = rng.multivariate_normal(np.zeros(6), S)
        wrong = NavEstimate(0.0, np.eye(4), start.velocity_w, np.zeros((3, 3)), "sequence", "x", d[:3], d[3:])
        res, _ = integrate_interval(imu, wrong, 1.0, params, settings)
        xis.append(gtsam.Pose3.Logmap(gtsam.Pose3(nominal.T_i0_i1).between(gtsam.Pose3(res.T_i0_i1))))
    ratio = np.diag(np.cov(np.array(xis).T)) / np.diag(nominal.covariance)
    assert np.all((ratio > 0.75) & (ratio < 1.3)), ratio  # 300 draws: +-3.5 sigma of a variance estimate
    without, _ = integrate_interval(imu, start, 1.0, params, ImuPoseSettings.uncalibrated(integration_sigma=1e-9))
    assert np.trace(without.covariance) < 1e-3 * np.trace(nominal.covariance)


def test_two_pose_velocity_covariance_holds_the_pose_noise():
    imu = _turning_imu()
    frames = [ground_truth_frames(np.array([0.0, 0.05, 0.1]), np.stack([make_transform(np.eye(3), [x, 0, 0])
                                  for x in (0.0, 0.05, 0.1)]), np.eye(4), _camera(), 20.0)[i] for i in range(2)]
    covs = []
    for s in (ImuPoseSettings(velocity_pose_sigma_m=1e-3), ImuPoseSettings.uncalibrated()):
        src = ImuPoseSource(imu, FrameList(frames, imu), s)
        v, cov = src._two_pose_velocity(frames[1], frames[1].T_w_c, 0, np.zeros(3), np.zeros(3))
        covs.append(cov)
    np.testing.assert_allclose(covs[0] - covs[1], np.eye(3) * 2 * 1e-3**2 / 0.05**2, rtol=1e-6, atol=1e-12)


def _camera():
    return Camera(64, 48, 50.0, 50.0, 31.5, 23.5)


def test_bias_scatter_grows_the_fit_covariance_only_where_fits_scatter_more():
    src = ImuPoseSource(_turning_imu(), settings=ImuPoseSettings(bias_scatter_window_s=10.0))
    fit_cov = np.diag([1e-6] * 3 + [1e-8] * 3)
    out = None
    for k, dy in enumerate([0.0, 0.1, -0.1, 0.05]):  # accelerometer y bias scatters by ~0.08 m/s^2
        fit = WindowFit(np.array([0.0, dy, 0.0]), np.zeros(3), np.zeros(3), np.eye(3), fit_cov)
        out = src._with_bias_scatter(float(k), fit)
    d = np.diag(out.bias_cov)
    assert d[1] == pytest.approx(np.var([0.0, 0.1, -0.1, 0.05], ddof=1))  # grown to the scatter
    np.testing.assert_allclose(d[[0, 2, 3, 4, 5]], np.diag(fit_cov)[[0, 2, 3, 4, 5]])  # kept where fits agree


def test_presets_and_settings():
    assert POSE_PRESETS["imu_real_mav"] == ImuPoseSettings(accel_noise_scale=10.0)
    assert POSE_PRESETS["imu"] == ImuPoseSettings() and ImuPoseSettings().bias_covariance
    base = ImuPoseSettings.uncalibrated()
    assert not base.bias_covariance and not base.pose_noise_in_velocity
    with pytest.raises(UnknownNameError, match="imu_real_mav"):
        POSE_PRESETS["imu_euroc"]
    with pytest.raises(SettingsError, match="accel_noise_scale"):
        ImuPoseSettings(accel_noise_scale=0.0)
    with pytest.raises(SettingsError, match="bias_scatter_window_s"):
        ImuPoseSettings(bias_scatter_window_s=-1.0)
