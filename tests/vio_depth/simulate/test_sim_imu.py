"""Trajectories have exact analytic derivatives; IMU samples are consistent with them."""

import numpy as np
import pytest

from vio_core.geometry import rotation_angle_deg
from vio_depth.simulate.generate import room_trajectory, street_trajectory
from vio_depth.simulate.imu import ImuNoise, ideal_imu, integrate_imu, simulate_imu
from vio_depth.simulate.trajectory import Sinusoids, SinusoidTrajectory

TRAJECTORIES = {"street": lambda: street_trajectory(101), "room": lambda: room_trajectory(202)}


def _skew_to_vec(S):
    return np.stack([S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0], S[..., 1, 0] - S[..., 0, 1]], -1) / 2


@pytest.mark.parametrize("name", sorted(TRAJECTORIES))
def test_analytic_derivatives_match_finite_differences(name):
    traj = TRAJECTORIES[name]()
    t = np.linspace(traj.t_start + 0.5, traj.t_end - 0.5, 25)
    h = 1e-4
    st, plus, minus = traj.state(t), traj.state(t + h), traj.state(t - h)
    np.testing.assert_allclose(st.v_w, (plus.p_w - minus.p_w) / (2 * h), atol=1e-5)
    np.testing.assert_allclose(st.a_w, (plus.v_w - minus.v_w) / (2 * h), atol=1e-4)
    # omega^ = R^T dR/dt
    dR = (plus.R_w_i - minus.R_w_i) / (2 * h)
    omega_fd = _skew_to_vec(np.einsum("kji,kjl->kil", st.R_w_i, dR))
    np.testing.assert_allclose(st.omega_i, omega_fd, atol=1e-6)
    assert np.abs(st.omega_i).max() > 0.05  # the motion really rotates


@pytest.mark.parametrize("name, t0", [("street", 6.5), ("street", 1.0), ("room", 2.0), ("room", 5.0)])
def test_noise_free_imu_integrated_over_one_second_reproduces_relative_pose(name, t0):
    traj = TRAJECTORIES[name]()
    t = t0 + np.arange(201) / 200.0  # 200 Hz, 1 s
    gyro, accel = ideal_imu(traj, t)
    st = traj.state(t)
    R, p, _ = integrate_imu(t, gyro, accel, st.R_w_i[0], st.p_w[0], st.v_w[0])
    R0 = st.R_w_i[0]
    dp_true = R0.T @ (st.p_w[-1] - st.p_w[0])
    dp_est = R0.T @ (p[-1] - st.p_w[0])
    assert np.linalg.norm(dp_est - dp_true) / np.linalg.norm(dp_true) < 1e-3  # << 1 %
    dR_true = R0.T @ st.R_w_i[-1]
    err_deg = rotation_angle_deg(dR_true.T @ (R0.T @ R[-1]))
    assert err_deg < 1e-3 * max(rotation_angle_deg(dR_true), 1.0)


def test_resting_imu_measures_plus_gravity_on_z():
    zero = np.zeros((3, 1))
    rest = SinusoidTrajectory(Sinusoids([1.0, 2.0, 3.0], [0, 0, 0], zero, zero, zero),
                              Sinusoids([0.3, 0, 0], [0, 0, 0], zero, zero, zero), 0.0, 1.0)
    gyro, accel = ideal_imu(rest, np.linspace(0, 1, 5))
    np.testing.assert_allclose(gyro, 0.0, atol=1e-12)
    np.testing.assert_allclose(accel, np.tile([0, 0, 9.81], (5, 1)), atol=1e-12)


def test_noise_statistics_and_determinism():
    traj = TRAJECTORIES["room"]()
    t = np.arange(1200) / 200.0
    noise = ImuNoise()
    imu, truth = simulate_imu(traj, t, np.eye(4), noise=noise, seed=4)
    gyro, accel = ideal_imu(traj, t)
    white_g = imu.gyro - gyro - truth["gyro_bias"]
    white_a = imu.accel - accel - truth["accel_bias"]
    np.testing.assert_allclose(white_g.std(0), noise.gyro_noise_density * np.sqrt(200), rtol=0.1)
    np.testing.assert_allclose(white_a.std(0), noise.accel_noise_density * np.sqrt(200), rtol=0.1)
    walk = np.diff(truth["accel_bias"], axis=0)
    np.testing.assert_allclose(walk.std(0), noise.accel_bias_random_walk / np.sqrt(200), rtol=0.1)
    assert imu.gyro_noise == noise.gyro_noise_density and imu.accel_bias_walk == noise.accel_bias_random_walk
    again, _ = simulate_imu(traj, t, np.eye(4), noise=noise, seed=4)
    assert np.array_equal(again.gyro, imu.gyro) and np.array_equal(again.accel, imu.accel)
    other, _ = simulate_imu(traj, t, np.eye(4), noise=noise, seed=5)
    assert not np.array_equal(other.gyro, imu.gyro)
    exact, truth0 = simulate_imu(traj, t, np.eye(4), noise=None)
    assert np.array_equal(exact.gyro, gyro) and not truth0["gyro_bias"].any()
