"""SIMULATED IMU samples exactly consistent with a smooth trajectory, plus a reference integrator.

Noise-free measurements at time t (IMU frame, world z up, ``g_w = (0, 0, -9.81)``):

    gyro(t)  = omega_i(t)                               body angular rate, rad/s
    accel(t) = R_w_i(t)^T (a_w(t) - g_w)                specific force, m/s^2

Noisy measurements (``ImuNoise``, sample spacing dt):

    gyro_k  = gyro(t_k)  + b_g,k + gyro_noise_density  / sqrt(dt) * n_k
    accel_k = accel(t_k) + b_a,k + accel_noise_density / sqrt(dt) * m_k
    b_g,k+1 = b_g,k + gyro_bias_random_walk  * sqrt(dt) * u_k,   b_g,0 ~ N(0, gyro_bias_init^2)
    b_a,k+1 = b_a,k + accel_bias_random_walk * sqrt(dt) * w_k,   b_a,0 ~ N(0, accel_bias_init^2)

with n, m, u, w i.i.d. standard normal 3-vectors from ``default_rng(seed)`` (drawn in the
order b_g,0, b_a,0, n, m, u, w).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError, SettingsError
from vio_core.geometry import so3_exp

from ..frame import ImuData
from .trajectory import Trajectory

GRAVITY_W = (0.0, 0.0, -9.81)


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise model (defaults: EuRoC / ADIS16448-like).

    Attributes:
        gyro_noise_density: rad/s/sqrt(Hz) white noise.
        accel_noise_density: m/s^2/sqrt(Hz) white noise.
        gyro_bias_random_walk: rad/s^2/sqrt(Hz).
        accel_bias_random_walk: m/s^3/sqrt(Hz).
        gyro_bias_init: rad/s standard deviation of the initial gyro bias (per axis).
        accel_bias_init: m/s^2 standard deviation of the initial accelerometer bias (per axis).
    """

    gyro_noise_density: float = 1.7e-4
    accel_noise_density: float = 2.0e-3
    gyro_bias_random_walk: float = 2.0e-5
    accel_bias_random_walk: float = 3.0e-3
    gyro_bias_init: float = 1.0e-3
    accel_bias_init: float = 2.0e-2

    def __post_init__(self):
        if any(v < 0 for v in asdict(self).values()):
            raise SettingsError("IMU noise parameters must be non-negative")

    def to_json(self) -> dict:
        return asdict(self)


def ideal_imu(trajectory: Trajectory, t, gravity_w=GRAVITY_W) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free ``(gyro (K, 3) rad/s, accel (K, 3) m/s^2)`` at ``t: (K,)`` seconds."""
    g = check_array("gravity_w", gravity_w, (3,), finite=True)
    st = trajectory.state(t)
    accel = np.einsum("kji,kj->ki", st.R_w_i, st.a_w - g)
    return st.omega_i.copy(), accel


def simulate_imu(trajectory: Trajectory, t, T_c_i, *, noise: ImuNoise | None = None, seed: int = 0,
                 gravity_w=GRAVITY_W) -> tuple[ImuData, dict]:
    """IMU samples along ``trajectory`` (which is the IMU's own trajectory).

    Args:
        t: (M,) seconds, strictly increasing, evenly spaced.
        T_c_i: (4, 4) IMU-to-camera transform stored with the samples.
        noise: noise model, or None for exact measurements.
        seed: RNG seed of the noise.

    Returns:
        (ImuData, truth) where truth holds the true biases: ``gyro_bias``, ``accel_bias`` (M, 3).
    """
    t = check_array("t", t, (None,), finite=True)
    T_c_i = check_transform("T_c_i", T_c_i)
    if len(t) < 2 or np.any(np.diff(t) <= 0):
        raise InputError("IMU times must be strictly increasing (at least 2)")
    dt = float(np.median(np.diff(t)))
    gyro, accel = ideal_imu(trajectory, t, gravity_w)
    m = len(t)
    bg = np.zeros((m, 3))
    ba = np.zeros((m, 3))
    model = ImuNoise(0, 0, 0, 0, 0, 0) if noise is None else noise
    if noise is not None:
        rng = np.random.default_rng(seed)
        bg0 = model.gyro_bias_init * rng.standard_normal(3)
        ba0 = model.accel_bias_init * rng.standard_normal(3)
        white_g = rng.standard_normal((m, 3)) * (model.gyro_noise_density / np.sqrt(dt))
        white_a = rng.standard_normal((m, 3)) * (model.accel_noise_density / np.sqrt(dt))
        walk_g = rng.standard_normal((m - 1, 3)) * (model.gyro_bias_random_walk * np.sqrt(dt))
        walk_a = rng.standard_normal((m - 1, 3)) * (model.accel_bias_random_walk * np.sqrt(dt))
        bg = bg0 + np.concatenate([np.zeros((1, 3)), np.cumsum(walk_g, axis=0)])
        ba = ba0 + np.concatenate([np.zeros((1, 3)), np.cumsum(walk_a, axis=0)])
        gyro = gyro + bg + white_g
        accel = accel + ba + white_a
    imu = ImuData(t=t.copy(), gyro=gyro, accel=accel, T_c_i=T_c_i,
                  gyro_noise=model.gyro_noise_density, accel_noise=model.accel_noise_density,
                  gyro_bias_walk=model.gyro_bias_random_walk, accel_bias_walk=model.accel_bias_random_walk,
                  gravity_w=tuple(float(v) for v in gravity_w))
    return imu, {"gyro_bias": bg, "accel_bias": ba}


def integrate_imu(t, gyro, accel, R_w_i0, p_w0, v_w0, gravity_w=GRAVITY_W):
    """Reference strapdown integration of bias-free IMU samples (trapezoidal / midpoint).

    Args:
        t: (M,) seconds. gyro: (M, 3) rad/s. accel: (M, 3) m/s^2 specific force.
        R_w_i0: (3, 3) initial IMU-to-world rotation. p_w0, v_w0: (3,) m and m/s at t[0].

    Returns:
        (R_w_i (M, 3, 3), p_w (M, 3) m, v_w (M, 3) m/s) at every sample time.
    """
    t = check_array("t", t, (None,), finite=True)
    gyro = check_array("gyro", gyro, (len(t), 3), finite=True)
    accel = check_array("accel", accel, (len(t), 3), finite=True)
    R = check_array("R_w_i0", R_w_i0, (3, 3), finite=True).copy()
    p = check_array("p_w0", p_w0, (3,), finite=True).copy()
    v = check_array("v_w0", v_w0, (3,), finite=True).copy()
    g = check_array("gravity_w", gravity_w, (3,), finite=True)
    Rs, ps, vs = [R.copy()], [p.copy()], [v.copy()]
    for k in range(len(t) - 1):
        dt = t[k + 1] - t[k]
        R_next = R @ so3_exp(0.5 * (gyro[k] + gyro[k + 1]) * dt)
        a0 = R @ accel[k] + g
        a1 = R_next @ accel[k + 1] + g
        p = p + v * dt + (2.0 * a0 + a1) * dt * dt / 6.0
        v = v + 0.5 * (a0 + a1) * dt
        R = R_next
        Rs.append(R.copy())
        ps.append(p.copy())
        vs.append(v.copy())
    return np.stack(Rs), np.stack(ps), np.stack(vs)
