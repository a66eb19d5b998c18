"""Gyroscope-only rotation between two instants (the KLT front end's prediction)."""

import numpy as np
from scipy.spatial.transform import Rotation

from vio_depth.frame import ImuData
from vio_depth.poses.gyro import camera_rotation, gyro_rotation


def imu_with_rate(rate, T_c_i=np.eye(4), hz: float = 200.0, seconds: float = 2.0) -> ImuData:
    t = np.arange(0.0, seconds, 1.0 / hz)
    return ImuData(t, np.tile(rate, (len(t), 1)), np.tile([0.0, 0.0, 9.81], (len(t), 1)), T_c_i)


def test_a_constant_rate_integrates_exactly_between_samples():
    rate = np.array([0.3, -0.2, 0.5])
    imu = imu_with_rate(rate)
    t0, t1 = 0.1234, 0.1734  # ends between samples
    R = gyro_rotation(imu, t0, t1)
    np.testing.assert_allclose(R, Rotation.from_rotvec(rate * (t1 - t0)).as_matrix(), atol=1e-12)
    bias = np.array([0.1, 0.0, 0.0])
    np.testing.assert_allclose(gyro_rotation(imu, t0, t1, bias),
                               Rotation.from_rotvec((rate - bias) * (t1 - t0)).as_matrix(), atol=1e-12)


def test_a_varying_rate_composes_in_order():
    t = np.arange(0.0, 1.0, 0.005)
    gyro = np.column_stack([np.sin(3 * t), np.cos(2 * t), 0.5 * t])
    imu = ImuData(t, gyro, np.tile([0.0, 0.0, 9.81], (len(t), 1)), np.eye(4))
    # reference: fine Euler steps of the same linearly interpolated rate
    ts = np.linspace(0.2, 0.6, 40001)
    w = np.stack([np.interp(ts, t, gyro[:, k]) for k in range(3)], axis=1)
    R = np.eye(3)
    for step in 0.5 * (w[1:] + w[:-1]) * np.diff(ts)[:, None]:
        R = R @ Rotation.from_rotvec(step).as_matrix()
    np.testing.assert_allclose(gyro_rotation(imu, 0.2, 0.6), R, atol=1e-5)


def test_camera_rotation_maps_through_the_extrinsics_and_needs_coverage():
    R_c_i = Rotation.from_euler("xyz", [90, 0, 90], degrees=True).as_matrix()
    T_c_i = np.eye(4)
    T_c_i[:3, :3] = R_c_i
    rate = np.array([0.0, 0.0, 1.0])  # about the IMU's z
    imu = imu_with_rate(rate, T_c_i)
    R = camera_rotation(imu, 0.5, 0.6)
    # a direction fixed in the world: in the IMU frames d_i1 = R_i0_i1^T d_i0
    d_i0 = np.array([1.0, 0.0, 0.0])
    R_i0_i1 = Rotation.from_rotvec(rate * 0.1).as_matrix()
    np.testing.assert_allclose(R @ (R_c_i @ d_i0), R_c_i @ (R_i0_i1.T @ d_i0), atol=1e-12)
    assert camera_rotation(imu, 1.9, 2.5) is None  # beyond the samples
