"""IMU preintegration with gtsam: intervals, checkpoints, the bias/velocity window fit.

The IMU pose source that uses these is :class:`vio_depth.poses.imu.ImuPoseSource`; the
conventions (gtsam ``Pose3`` right perturbation, rotation first) are in its module docstring.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.checks import check_array, check_transform
from vio_core.geometry import invert_transform

from ..frame import ImuData
from .imu_state import ImuPoseSettings, NavEstimate


@dataclass(frozen=True)
class ImuIntegration:
    """Result of integrating one interval.

    Attributes:
        T_i0_i1: (4, 4) relative IMU pose (later IMU frame to earlier IMU frame), metres.
        end: navigation state at the end of the interval.
        covariance: (6, 6) right-perturbation covariance of ``T_i0_i1`` (rotation rad,
            then translation m, in the later IMU frame).
        preintegration_cov: (9, 9) gtsam preintegration covariance of (rotation,
            position, velocity) increments, earlier IMU frame.
    """

    T_i0_i1: np.ndarray
    end: NavEstimate
    covariance: np.ndarray
    preintegration_cov: np.ndarray


def _interval_samples(imu: ImuData, t0: float, t1: float, max_gap: float):
    """Knots ``[t0, samples inside, t1]`` with linearly interpolated gyro/accel, or ``(None, reason)``.

    The samples supporting the interval (those inside plus the one at or before ``t0``
    and the one at or after ``t1``) must be at most ``max_gap`` apart; an end may lie
    up to ``max_gap / 2`` outside the recorded samples (the end value is held).
    """
    t = imu.t
    i0 = int(np.searchsorted(t, t0, side="right")) - 1  # last sample <= t0
    i1 = int(np.searchsorted(t, t1, side="left"))  # first sample >= t1
    if (i0 < 0 and t[0] - t0 > 0.5 * max_gap) or (i1 >= len(t) and t1 - t[-1] > 0.5 * max_gap):
        return None, f"IMU samples cover {t[0]:.3f}..{t[-1]:.3f} s, not the interval {t0:.3f}..{t1:.3f} s"
    support = t[max(i0, 0):min(i1, len(t) - 1) + 1]
    widest = float(np.max(np.diff(support))) if len(support) > 1 else 0.0
    if widest > max_gap:
        return None, f"IMU gap of {widest:.3f} s (> {max_gap} s) between {t0:.3f} and {t1:.3f} s"
    knots = np.concatenate([[t0], t[(t > t0) & (t < t1)], [t1]])
    gyro = np.stack([np.interp(knots, t, imu.gyro[:, k]) for k in range(3)], axis=1)
    accel = np.stack([np.interp(knots, t, imu.accel[:, k]) for k in range(3)], axis=1)
    return (knots, gyro, accel), ""


def import_gtsam():
    """The ``gtsam`` module, imported now (a core dependency, pyproject.toml, imported only
    where ``--poses imu`` / ``vio`` are used: it takes 0.1-0.5 s). A stream's IMU pose source
    is built at its first frame; importing gtsam when the stream is built spares that frame."""
    import gtsam

    return gtsam



def preintegration_params(imu: ImuData, settings: ImuPoseSettings = ImuPoseSettings()):
    """``gtsam.PreintegrationCombinedParams`` from the IMU's noise densities (times the
    settings' noise scales) and gravity."""
    gtsam = import_gtsam()
    p = gtsam.PreintegrationCombinedParams(np.asarray(imu.gravity_w, dtype=np.float64))
    eye = np.eye(3)
    p.setAccelerometerCovariance(eye * (settings.accel_noise_scale * imu.accel_noise)**2)
    p.setGyroscopeCovariance(eye * (settings.gyro_noise_scale * imu.gyro_noise)**2)
    p.setIntegrationCovariance(eye * settings.integration_sigma**2)
    p.setBiasAccCovariance(eye * imu.accel_bias_walk**2)
    p.setBiasOmegaCovariance(eye * imu.gyro_bias_walk**2)
    return p


def _pieces(imu: ImuData, t0: float, t1: float, max_gap: float, extra_knots=()):
    """Piecewise-linear integration pieces over [t0, t1]: ``(knots, acc, gyro, dts)`` or ``(None, reason)``.

    Each piece between consecutive knots (samples, ends and ``extra_knots``) uses the
    mean of its two end values; gtsam applies a piece's specific force with the
    orientation at the piece's start, so the mean force is rotated back by half the
    piece's rotation, which keeps the scheme second order in the sample period.
    """
    samples, reason = _interval_samples(imu, t0, t1, max_gap)
    if samples is None:
        return None, reason
    knots, gyro, accel = samples
    extra = np.asarray(extra_knots, dtype=np.float64)
    if len(extra):
        knots = np.union1d(knots, extra[(extra > t0) & (extra < t1)])
        gyro = np.stack([np.interp(knots, imu.t, imu.gyro[:, k]) for k in range(3)], axis=1)
        accel = np.stack([np.interp(knots, imu.t, imu.accel[:, k]) for k in range(3)], axis=1)
    dts = np.diff(knots)
    gyr = 0.5 * (gyro[1:] + gyro[:-1])
    acc = Rotation.from_rotvec(0.5 * gyr * dts[:, None]).apply(0.5 * (accel[1:] + accel[:-1]))
    return (knots, acc, gyr, dts), ""


def _bias(gtsam, accel_bias, gyro_bias):
    return gtsam.imuBias.ConstantBias(np.asarray(accel_bias, float), np.asarray(gyro_bias, float))


def preintegrate(imu: ImuData, t0: float, t1: float, params, accel_bias, gyro_bias,
                 max_gap: float) -> tuple[object | None, str]:
    """``gtsam.PreintegratedCombinedMeasurements`` of the samples from ``t0`` to ``t1`` seconds.

    Args:
        imu, params: samples and gtsam parameters (:func:`preintegration_params`).
        t0, t1: seconds, ``t0 <= t1``.
        accel_bias, gyro_bias: (3,) m/s^2 and rad/s, the linearisation point of the biases.
        max_gap: largest accepted gap between IMU samples, seconds.

    Returns:
        ``(pim, "")`` or ``(None, reason)`` when the IMU does not cover the interval.
    """
    gtsam = import_gtsam()
    if not t1 >= t0:
        return None, f"end time {t1:.3f} s is before start time {t0:.3f} s"
    pim = gtsam.PreintegratedCombinedMeasurements(params, _bias(gtsam, accel_bias, gyro_bias))
    if t1 > t0:
        pieces, reason = _pieces(imu, t0, t1, max_gap)
        if pieces is None:
            return None, reason
        _, acc, gyr, dts = pieces
        for a, w, dt in zip(acc, gyr, dts):  # one gtsam call per IMU sample
            if dt > 0:
                pim.integrateMeasurement(a, w, float(dt))
    return pim, ""


def integrate_interval(imu: ImuData, start: NavEstimate, t1: float, params=None,
                       settings: ImuPoseSettings = ImuPoseSettings()) -> tuple[ImuIntegration | None, str]:
    """Preintegrate the IMU from ``start.t`` to ``t1`` seconds and predict the state at ``t1``.

    Samples are treated as piecewise linear in time (see :func:`_pieces`); the biases
    are the start state's. The covariance holds the preintegration noise, the start
    velocity's covariance times ``dt^2`` and, with ``settings.bias_covariance``, the start
    state's ``bias_cov`` mapped through the prediction's bias Jacobian.

    Args:
        imu: the sequence's IMU samples.
        start: navigation state at the start (its ``T_w_i`` (4, 4), ``velocity_w`` (3,) m/s,
            biases).
        t1: end time, seconds (>= ``start.t``).
        params: ``gtsam.PreintegrationCombinedParams`` (built from ``imu`` when None).
        settings: sample gaps, noise scales, the bias term.

    Returns:
        ``(ImuIntegration, "")`` or ``(None, reason)`` when the IMU does not cover the interval.
    """
    gtsam = import_gtsam()
    check_transform("start.T_w_i", start.T_w_i)
    check_array("start.velocity_w", start.velocity_w, (3,), finite=True)
    t0 = float(start.t)
    if not t1 >= t0:
        return None, f"end time {t1:.3f} s is before start time {t0:.3f} s"
    if params is None:
        params = preintegration_params(imu, settings)
    bias = _bias(gtsam, start.accel_bias, start.gyro_bias)
    pim, reason = preintegrate(imu, t0, t1, params, start.accel_bias, start.gyro_bias, settings.max_sample_gap_s)
    if pim is None:
        return None, reason
    state0 = gtsam.NavState(gtsam.Rot3(start.T_w_i[:3, :3]), start.T_w_i[:3, 3].copy(), start.velocity_w.copy())
    H_bias = np.zeros((9, 6), order="F")  # d(end state (rotation, position, velocity; end frame)) / d(accel, gyro bias)
    state1 = pim.predict(state0, bias, np.zeros((9, 9), order="F"), H_bias)
    T_w_i1 = state1.pose().matrix()
    if not (np.all(np.isfinite(T_w_i1)) and np.all(np.isfinite(np.asarray(state1.velocity(), float)))):
        return None, f"IMU preintegration from {t0:.3f} s to {t1:.3f} s gave non-finite values"
    T_i0_i1 = invert_transform(start.T_w_i) @ T_w_i1

    dt = t1 - t0
    R_w_i0 = start.T_w_i[:3, :3]
    C = np.asarray(pim.preintMeasCov())[:9, :9] if t1 > t0 else np.zeros((9, 9))  # (theta, p, v), earlier frame
    C_rt = C[:6, :6].copy()
    C_rt[3:, 3:] += dt**2 * R_w_i0.T @ start.velocity_cov @ R_w_i0
    J = np.eye(6)
    J[3:, 3:] = T_i0_i1[:3, :3].T  # translation error: earlier frame -> later (Pose3 right perturbation)
    cov = J @ C_rt @ J.T
    vel_cov = start.velocity_cov + R_w_i0 @ C[6:9, 6:9] @ R_w_i0.T
    if settings.bias_covariance and np.any(start.bias_cov):
        B = H_bias @ np.asarray(start.bias_cov, float) @ H_bias.T  # end-frame tangent, like Pose3's right perturbation
        cov = cov + B[:6, :6]
        R_w_i1 = T_w_i1[:3, :3]
        vel_cov = vel_cov + R_w_i1 @ B[6:9, 6:9] @ R_w_i1.T
    moved = t1 > t0
    end = replace(start, t=float(t1), T_w_i=T_w_i1, velocity_w=np.asarray(state1.velocity(), float).reshape(3),
                  velocity_cov=vel_cov, pose_source="estimate" if moved else start.pose_source,
                  velocity_source="estimate" if moved else start.velocity_source)
    return ImuIntegration(T_i0_i1, end, 0.5 * (cov + cov.T), C), ""


def preintegrate_checkpoints(imu: ImuData, params, t0: float, times, accel_bias, gyro_bias,
                             max_gap: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Preintegrated increments from ``t0`` to each of ``times``.

    Args:
        imu, params: samples and gtsam parameters.
        t0: start, seconds.
        times: (K,) seconds, increasing, > ``t0``.
        accel_bias, gyro_bias: (3,) biases subtracted from the samples.
        max_gap: largest accepted gap between IMU samples, seconds.

    Returns:
        ``(dR (K, 3, 3), dp (K, 3) m, dv (K, 3) m/s)`` in the IMU frame at ``t0`` (without
        gravity), or None when the IMU does not cover ``[t0, times[-1]]``.
    """
    gtsam = import_gtsam()
    times = check_array("times", times, (None,), finite=True)
    pieces, _ = _pieces(imu, t0, float(times[-1]), max_gap, times)
    if pieces is None:
        return None
    knots, acc, gyr, dts = pieces
    pim = gtsam.PreintegratedCombinedMeasurements(params, _bias(gtsam, accel_bias, gyro_bias))
    ends = set(np.searchsorted(knots, times).tolist())
    dR, dp, dv = [], [], []
    for k, (a, w, dt) in enumerate(zip(acc, gyr, dts), start=1):
        if dt > 0:
            pim.integrateMeasurement(a, w, float(dt))
        if k in ends:
            dR.append(pim.deltaRij().matrix())
            dp.append(np.asarray(pim.deltaPij(), float).reshape(3))
            dv.append(np.asarray(pim.deltaVij(), float).reshape(3))
    return np.array(dR), np.array(dp), np.array(dv)


@dataclass(frozen=True)
class WindowFit:
    """Biases and velocity fitted to a window of past poses (see :func:`fit_window`).

    Attributes:
        accel_bias: (3,) m/s^2. gyro_bias: (3,) rad/s.
        velocity_w: (3,) m/s IMU velocity at the last frame of the window.
        velocity_cov: (3, 3) (m/s)^2 its covariance (from the fit's assumed noise).
        bias_cov: (6, 6) covariance of (accel_bias, gyro_bias) from the same least squares.
    """

    accel_bias: np.ndarray
    gyro_bias: np.ndarray
    velocity_w: np.ndarray
    velocity_cov: np.ndarray
    bias_cov: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))


def fit_window(imu: ImuData, params, times, T_w_i, settings: ImuPoseSettings = ImuPoseSettings()) -> WindowFit | None:
    """Fit the IMU biases and velocity to the poses of a window of frames.

    Model (``tau_k = t_k - t_0``, increments from ``t_0`` with biases ``b``):
    ``R_k = R_0 dR_k(b_g)`` and ``p_k = p_0 + v_0 tau_k + g tau_k^2 / 2 + R_0 dp_k(b_a, b_g)``.
    The increments are linearised in the biases around the prior (numerical Jacobians
    from re-integrating with perturbed biases); the gyroscope bias is solved from the
    rotations, then ``v_0`` and the accelerometer bias from the positions, each a
    weighted linear least-squares problem with a Gaussian prior on the bias. The
    velocity at the last frame follows from ``v_0`` and the integration.

    Args:
        imu, params: IMU samples and gtsam parameters.
        times: (K,) seconds, increasing (K >= 3).
        T_w_i: (K, 4, 4) IMU-to-world poses at ``times``.
        settings: priors, pose noise, gaps.

    Returns:
        :class:`WindowFit`, or None when the IMU does not cover the window.
    """
    times = check_array("times", times, (None,), finite=True)
    T = check_array("T_w_i", T_w_i, (len(times), 4, 4), finite=True)
    if len(times) < 3:
        return None
    t0, tk = float(times[0]), times[1:]
    tau = tk - t0
    b_a0 = np.asarray(settings.accel_bias, float)
    b_g0 = np.asarray(settings.gyro_bias, float)
    gap = settings.max_sample_gap_s
    nominal = preintegrate_checkpoints(imu, params, t0, tk, b_a0, b_g0, gap)
    if nominal is None:
        return None
    dR, dp, dv = nominal
    eps_a, eps_g = 1e-2, 1e-4
    Hr_g = np.zeros((len(tk), 3, 3))
    Hp_a, Hp_g, Hv_a, Hv_g = (np.zeros((len(tk), 3, 3)) for _ in range(4))
    for i in range(3):
        e = np.eye(3)[i]
        dR_a, dp_a, dv_a = preintegrate_checkpoints(imu, params, t0, tk, b_a0 + eps_a * e, b_g0, gap)
        dR_g, dp_g, dv_g = preintegrate_checkpoints(imu, params, t0, tk, b_a0, b_g0 + eps_g * e, gap)
        Hp_a[:, :, i], Hv_a[:, :, i] = (dp_a - dp) / eps_a, (dv_a - dv) / eps_a
        Hp_g[:, :, i], Hv_g[:, :, i] = (dp_g - dp) / eps_g, (dv_g - dv) / eps_g
        Hr_g[:, :, i] = Rotation.from_matrix(np.transpose(dR, (0, 2, 1)) @ dR_g).as_rotvec() / eps_g

    R0, p0 = T[0, :3, :3], T[0, :3, 3]
    g = np.asarray(imu.gravity_w, float)
    # gyroscope bias from the rotations
    r = Rotation.from_matrix(np.transpose(dR, (0, 2, 1)) @ R0.T @ T[1:, :3, :3]).as_rotvec()  # (K-1, 3)
    gyro_noise = settings.gyro_noise_scale * imu.gyro_noise
    accel_noise = settings.accel_noise_scale * imu.accel_noise
    w_r = 1.0 / np.sqrt(gyro_noise**2 * tau + 2 * settings.pose_sigma_rad**2)
    A = (Hr_g * w_r[:, None, None]).reshape(-1, 3)
    y = (r * w_r[:, None]).reshape(-1)
    P = np.eye(3) / settings.gyro_bias_prior_sigma**2
    N_g = A.T @ A + P
    db_g = np.linalg.solve(N_g, A.T @ y)
    # velocity at t0 (in the IMU frame at t0) and accelerometer bias from the positions
    e_p = (T[1:, :3, 3] - p0 - 0.5 * np.outer(tau**2, g)) @ R0 - dp - Hp_g @ db_g  # (K-1, 3)
    w_p = 1.0 / np.sqrt(accel_noise**2 * tau**3 / 3.0 + 2 * settings.pose_sigma_m**2)
    A = np.concatenate([np.eye(3)[None] * tau[:, None, None], Hp_a], axis=2) * w_p[:, None, None]
    A = A.reshape(-1, 6)
    y = (e_p * w_p[:, None]).reshape(-1)
    P = np.zeros((6, 6))
    P[3:, 3:] = np.eye(3) / settings.accel_bias_prior_sigma**2
    N = A.T @ A + P
    x = np.linalg.solve(N, A.T @ y)
    cov_x = np.linalg.inv(N)
    u0, db_a = x[:3], x[3:]
    # velocity at the last frame
    J = np.hstack([np.eye(3), Hv_a[-1]])
    v_last = R0 @ (u0 + dv[-1] + Hv_a[-1] @ db_a + Hv_g[-1] @ db_g) + g * tau[-1]
    cov_v = R0 @ J @ cov_x @ J.T @ R0.T
    bias_cov = np.zeros((6, 6))
    bias_cov[:3, :3] = cov_x[3:, 3:]
    bias_cov[3:, 3:] = np.linalg.inv(N_g)  # the two solves are sequential: cross terms left out
    return WindowFit(b_a0 + db_a, b_g0 + db_g, v_last, 0.5 * (cov_v + cov_v.T), 0.5 * (bias_cov + bias_cov.T))


def gravity_aligned_rotation(mean_accel, gravity_w) -> np.ndarray:
    """(3, 3) ``R_w_i`` such that the IMU reading ``mean_accel`` (3,) m/s^2 opposes ``gravity_w`` (3,) m/s^2.

    The yaw is arbitrary (the minimal rotation between the two directions).
    """
    a = check_array("mean_accel", mean_accel, (3,), finite=True)
    g = check_array("gravity_w", gravity_w, (3,), finite=True)
    up_i = a / np.linalg.norm(a)
    up_w = -g / np.linalg.norm(g)
    rot, _ = Rotation.align_vectors(up_w[None, :], up_i[None, :])
    return rot.as_matrix()
