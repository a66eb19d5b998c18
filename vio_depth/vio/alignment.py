"""Visual-inertial alignment: scale, gravity, velocities and gyroscope bias of an
up-to-scale reconstruction (VINS-Mono's initial alignment, our derivation).

Inputs: the keyframes' camera poses ``T_c0_ck`` from :mod:`.sfm` (translations ``p_k`` up to
the scale ``s``) and the IMU between consecutive keyframes. With ``R_k = R_c0_ck R_ci`` the
IMU orientation in the first camera's frame and ``t_ci`` the IMU's position in the camera
frame, the IMU position is ``s p_k + R_c0_ck t_ci``. Preintegration from keyframe ``i`` to
``j = i + 1`` (``dt``, increments ``dR``, ``dp``, ``dv`` in IMU frame ``i``, accelerometer bias
taken as zero -- it is not observable this early) gives:

1. **gyroscope bias**: ``dR(b_g)`` must equal ``R_i^T R_j``; linearising ``dR`` in ``b_g``
   (numerical Jacobian) gives a 3-parameter least-squares problem over all pairs;
2. **scale, gravity, velocities**, linear once the bias is fixed::

       R_i^T (s (p_j - p_i) - v_i dt - g dt^2 / 2) = dp - R_i^T (R_c0_cj - R_c0_ci) t_ci
       R_i^T (v_j - v_i - g dt)                    = dv

   with unknowns ``v_k`` (IMU velocities in the first camera's frame), ``g`` (gravity
   there) and ``s``, solved by least squares;
3. **gravity refinement**: ``|g|`` is then imposed (``g = |g| g0/|g0| + B w`` with ``B`` two
   tangent directions, re-solved a few times).

Checks (each a refusal with a reason, :class:`Alignment`): ``|g|`` before refinement within
``max_gravity_error`` of the true magnitude, ``s > 0``, the scale's relative 1-sigma (from
the residuals) at most ``max_scale_sigma``, the IMU's acceleration change over the
keyframes at least ``min_acceleration`` (uniform motion leaves the scale unobservable),
and a plausible gyroscope bias. The world frame of the result has gravity along
``ImuData.gravity_w``, its origin and yaw at the first camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.checks import check_array
from vio_core.geometry import make_transform

from ..frame import ImuData
from ..poses import gravity_aligned_rotation, preintegrate
from .settings import VioInitSettings


@dataclass(frozen=True)
class Alignment:
    """Result of :func:`align`.

    Attributes:
        ok: True when every check passed; ``reason`` says which failed.
        scale: metres per reconstruction unit. scale_sigma: its relative 1-sigma.
        gravity_error: ``|g_est| - |g|`` m/s^2 before the magnitude was imposed.
        excitation: RMS change of the IMU's acceleration over the keyframes, m/s^2.
        gyro_bias: (3,) rad/s.
        T_w_c: (K, 4, 4) metric camera-to-world poses (gravity along ``gravity_w``).
        velocity_w: (K, 3) m/s IMU velocities in that world.
        tilt_sigma: rad, roll/pitch uncertainty implied by the gravity estimate.
    """

    ok: bool
    reason: str = ""
    scale: float = float("nan")
    scale_sigma: float = float("nan")
    gravity_error: float = float("nan")
    excitation: float = float("nan")
    gyro_bias: np.ndarray | None = None
    T_w_c: np.ndarray | None = None
    velocity_w: np.ndarray | None = None
    tilt_sigma: float = float("nan")


def _increments(imu: ImuData, params, times, gyro_bias, max_gap):
    """Per consecutive pair: (dt, dR (3, 3), dp (3,), dv (3,)) with accelerometer bias 0, or None."""
    out = []
    for t0, t1 in zip(times[:-1], times[1:]):
        pim, _ = preintegrate(imu, float(t0), float(t1), params, np.zeros(3), gyro_bias, max_gap)
        if pim is None:
            return None
        out.append((float(t1 - t0), pim.deltaRij().matrix(), np.asarray(pim.deltaPij(), float).reshape(3),
                    np.asarray(pim.deltaVij(), float).reshape(3)))
    return out


def estimate_gyro_bias(imu: ImuData, params, times, R_imu, max_gap: float, iterations: int = 2) -> np.ndarray | None:
    """Gyroscope bias (3,) rad/s making the preintegrated rotations match ``R_imu: (K, 3, 3)``
    (IMU-to-reference rotations at ``times: (K,)``), or None when the IMU does not cover them."""
    b = np.zeros(3)
    eps = 1e-4
    for _ in range(iterations):
        base = _increments(imu, params, times, b, max_gap)
        if base is None:
            return None
        rows, rhs = [], []
        J = np.zeros((len(base), 3, 3))
        for a in range(3):
            pert = _increments(imu, params, times, b + eps * np.eye(3)[a], max_gap)
            for k, ((_, dR, _, _), (_, dR2, _, _)) in enumerate(zip(base, pert)):
                J[k, :, a] = Rotation.from_matrix(dR.T @ dR2).as_rotvec() / eps
        for k, (_, dR, _, _) in enumerate(base):
            target = R_imu[k].T @ R_imu[k + 1]
            rows.append(J[k])
            rhs.append(Rotation.from_matrix(dR.T @ target).as_rotvec())
        A, y = np.concatenate(rows), np.concatenate(rhs)
        b = b + np.linalg.lstsq(A, y, rcond=None)[0]
    return b


def _tangent_basis(g: np.ndarray) -> np.ndarray:
    """(3, 2) two unit vectors orthogonal to ``g`` and each other."""
    a = g / np.linalg.norm(g)
    tmp = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    b1 = tmp - a * (a @ tmp)
    b1 /= np.linalg.norm(b1)
    return np.column_stack([b1, np.cross(a, b1)])


def _solve(inc, R_imu, R_cam, p, t_ci, gravity=None):
    """Least squares of the alignment equations. ``gravity``: None (free 3-vector) or (g0 (3,), B (3, 2))
    (``g = g0 + B w``). Returns (x, covariance of x, residual RMS, n_unknown_velocity)."""
    K = len(p)
    n_g = 3 if gravity is None else 2
    n = 3 * K + n_g + 1
    A, y = [], []
    for i, (dt, _, dp, dv) in enumerate(inc):
        j = i + 1
        Ri = R_imu[i]
        # position rows
        Ap = np.zeros((3, n))
        Ap[:, 3 * i:3 * i + 3] = -Ri.T * dt
        Gp = -0.5 * Ri.T * dt * dt
        yp = dp - Ri.T @ (R_cam[j] - R_cam[i]) @ t_ci
        Ap[:, -1] = Ri.T @ (p[j] - p[i])
        # velocity rows
        Av = np.zeros((3, n))
        Av[:, 3 * j:3 * j + 3] = Ri.T
        Av[:, 3 * i:3 * i + 3] = -Ri.T
        Gv = -Ri.T * dt
        yv = dv.copy()
        if gravity is None:
            Ap[:, 3 * K:3 * K + 3] = Gp
            Av[:, 3 * K:3 * K + 3] = Gv
        else:
            g0, B = gravity
            Ap[:, 3 * K:3 * K + 2] = Gp @ B
            Av[:, 3 * K:3 * K + 2] = Gv @ B
            yp = yp - Gp @ g0
            yv = yv - Gv @ g0
        A += [Ap, Av]
        y += [yp, yv]
    A, y = np.concatenate(A), np.concatenate(y)
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = A @ x - y
    dof = max(len(y) - n, 1)
    sigma2 = float(r @ r) / dof
    cov = sigma2 * np.linalg.pinv(A.T @ A)
    return x, cov, float(np.sqrt(np.mean(r * r)))


def align(T_c0_c, times, imu: ImuData, params, settings: VioInitSettings, max_gap: float) -> Alignment:
    """Align an up-to-scale reconstruction with the IMU (see the module docstring).

    Args:
        T_c0_c: (K, 4, 4) camera-to-first-camera poses, translation up to scale.
        times: (K,) seconds, increasing.
        imu: the IMU samples (``T_c_i``, ``gravity_w``).
        params: gtsam preintegration parameters.
        settings: the initialisation's checks.
        max_gap: largest accepted gap between IMU samples, seconds.
    """
    T = check_array("T_c0_c", T_c0_c, (None, 4, 4), finite=True)
    times = check_array("times", times, (len(T),), finite=True)
    K = len(T)
    R_ci, t_ci = imu.T_c_i[:3, :3], imu.T_c_i[:3, 3]
    R_cam = T[:, :3, :3]
    R_imu = R_cam @ R_ci
    p = T[:, :3, 3]
    G = float(np.linalg.norm(imu.gravity_w))
    b_g = estimate_gyro_bias(imu, params, times, R_imu, max_gap)
    if b_g is None:
        return Alignment(False, "the IMU does not cover the initialisation keyframes")
    if not np.linalg.norm(b_g) <= settings.max_gyro_bias:
        return Alignment(False, f"implausible gyroscope bias {np.linalg.norm(b_g):.3f} rad/s "
                                f"(> {settings.max_gyro_bias})", gyro_bias=b_g)
    inc = _increments(imu, params, times, b_g, max_gap)
    # excitation: the specific force, rotated into one frame, must change (else the scale is unobservable)
    f = np.array([R_imu[i] @ dv / dt for i, (dt, _, _, dv) in enumerate(inc)])
    excitation = float(np.sqrt(np.mean(np.sum((f - f.mean(0)) ** 2, axis=1)))) if len(f) > 1 else 0.0
    if excitation < settings.min_acceleration:
        return Alignment(False, f"too little excitation: the acceleration changes by {excitation:.3f} m/s^2 RMS "
                                f"(< {settings.min_acceleration})", excitation=excitation, gyro_bias=b_g)
    x, cov, _ = _solve(inc, R_imu, R_cam, p, t_ci)
    g_est, s = x[3 * K:3 * K + 3], float(x[-1])
    gravity_error = float(np.linalg.norm(g_est) - G)
    base = dict(gravity_error=gravity_error, excitation=excitation, gyro_bias=b_g)
    if not abs(gravity_error) <= settings.max_gravity_error:
        return Alignment(False, f"implausible gravity: |g| = {np.linalg.norm(g_est):.2f} m/s^2 "
                                f"(expected {G:.2f} +- {settings.max_gravity_error})", scale=s, **base)
    g = g_est / np.linalg.norm(g_est) * G
    for _ in range(4):
        B = _tangent_basis(g)
        x, cov, _ = _solve(inc, R_imu, R_cam, p, t_ci, (g, B))
        g = g + B @ x[3 * K:3 * K + 2]
        g = g / np.linalg.norm(g) * G
    s = float(x[-1])
    scale_sigma = float(np.sqrt(max(cov[-1, -1], 0.0)) / abs(s)) if s != 0 else float("inf")
    tilt_sigma = float(np.sqrt(max(np.trace(cov[3 * K:3 * K + 2, 3 * K:3 * K + 2]), 0.0) / 2) / G)
    base.update(scale=s, scale_sigma=scale_sigma)
    if not s > 0:
        return Alignment(False, f"implausible scale {s:.4g} (not positive)", **base)
    if not scale_sigma <= settings.max_scale_sigma:
        return Alignment(False, f"too little excitation: the scale is known to {scale_sigma:.1%} "
                                f"(> {settings.max_scale_sigma:.0%})", **base)
    R_w_c0 = gravity_aligned_rotation(-g, np.asarray(imu.gravity_w, float))
    T_w_c = np.stack([make_transform(R_w_c0 @ R_cam[k], R_w_c0 @ (s * (p[k] - p[0]))) for k in range(K)])
    v = (R_w_c0 @ x[:3 * K].reshape(K, 3).T).T
    return Alignment(True, "", T_w_c=T_w_c, velocity_w=v, tilt_sigma=tilt_sigma, **base)
