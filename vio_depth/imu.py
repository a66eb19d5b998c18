"""``--poses imu``: relative camera poses from IMU preintegration (gtsam).

For a keyframe and a later frame, the IMU samples between their timestamps are
preintegrated (``gtsam.PreintegratedCombinedMeasurements``) and applied to the
keyframe's navigation state (orientation, position, velocity, biases), with gravity
``ImuData.gravity_w``. The predicted IMU pose is mapped to the camera with ``T_c_i``:

    T_kf_cur = T_c_i (T_w_i(kf)^-1 T_w_i(cur)) T_c_i^-1

Where the keyframe's navigation state comes from, in this order:

* orientation and position: the sequence's pose of the keyframe (``T_w_c T_c_i``); else
  this source's own previous estimate at that frame (it is stateful and streams
  forward); else, for the first frame of a sequence without poses, a static start
  (roll/pitch from the mean accelerometer reading, yaw 0, position 0) when
  ``assume_static_start`` is set.
* biases: fitted to the sequence's poses of the last ``bias_window_s`` seconds up to
  and including the keyframe (:func:`fit_window`, never the current frame); else the
  previous estimate's; else ``ImuPoseSettings.accel_bias`` / ``gyro_bias`` (zero).
* velocity: ``Frame.velocity_w`` when the dataset gives it (KITTI OXTS); else from the
  previous estimate -- with sequence poses, the previous frame's pose plus the IMU in
  between (with the fitted biases), or the window fit's velocity when the previous frame
  has no pose, both drift-free because they are re-anchored on the poses at every
  keyframe; without poses, the chained dead-reckoning state -- else an IMU-aided
  finite difference with the next frame's pose (only the first frame of a posed
  sequence: it looks one frame ahead); else zero under ``assume_static_start``.

What drifts, and when not to trust this path:

* Only the gravity direction (roll/pitch), the velocity and the biases of the keyframe
  state enter the relative pose; yaw and position do not. A velocity error ``dv`` gives
  a translation error ``dv * dt``; a roll/pitch error ``dtheta`` gives ``0.5 * 9.81 *
  dtheta * dt^2``; an accelerometer bias error ``b`` gives ``0.5 * b * dt^2``.
* Without poses (dead reckoning) the chained velocity random-walks with the
  accelerometer noise and grows *linearly in time* with any bias error: unbounded.
  With poses but before enough of them are seen (the first frames), the biases are the
  prior (zero): e.g. 0.04 m/s^2 costs 2 cm over 1 s.
* Low-rate IMU (KITTI sync: 10 Hz) integrates coarsely; MEMS-grade IMUs without bias
  estimation are only useful over short intervals (well under a second).
* Intervals longer than ``max_interval_s`` or with IMU gaps longer than
  ``max_sample_gap_s`` are refused (``RelativePose.ok`` False with a reason).

Covariance: the (6, 6) returned with each pose is the preintegration covariance of
(rotation, position) plus the keyframe velocity's covariance times ``dt^2``, mapped to
the camera relative pose. Convention (gtsam ``Pose3``): the true pose is
``T_kf_cur @ Exp([omega, nu])`` with ``omega`` rad (rotation first) and ``nu`` metres,
both in the *current* camera frame. It does not include the keyframe orientation's error
(zero with sequence poses) nor the error of the bias estimate.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError
from vio_core.geometry import invert_transform
from .poses import RelativePose
from .types import Frame, ImuData


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


def _gtsam():
    import gtsam  # a core dependency (pyproject.toml), imported only when --poses imu is used

    return gtsam


def preintegration_params(imu: ImuData, settings: ImuPoseSettings = ImuPoseSettings()):
    """``gtsam.PreintegrationCombinedParams`` from the IMU's noise densities and gravity."""
    gtsam = _gtsam()
    p = gtsam.PreintegrationCombinedParams(np.asarray(imu.gravity_w, dtype=np.float64))
    eye = np.eye(3)
    p.setAccelerometerCovariance(eye * imu.accel_noise**2)
    p.setGyroscopeCovariance(eye * imu.gyro_noise**2)
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
    from scipy.spatial.transform import Rotation

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


def integrate_interval(imu: ImuData, start: NavEstimate, t1: float, params=None,
                       settings: ImuPoseSettings = ImuPoseSettings()) -> tuple[ImuIntegration | None, str]:
    """Preintegrate the IMU from ``start.t`` to ``t1`` seconds and predict the state at ``t1``.

    Samples are treated as piecewise linear in time (see :func:`_pieces`); the biases
    are the start state's.

    Args:
        imu: the sequence's IMU samples.
        start: navigation state at the start (its ``T_w_i`` (4, 4), ``velocity_w`` (3,) m/s,
            biases).
        t1: end time, seconds (>= ``start.t``).
        params: ``gtsam.PreintegrationCombinedParams`` (built from ``imu`` when None).
        settings: sample gaps.

    Returns:
        ``(ImuIntegration, "")`` or ``(None, reason)`` when the IMU does not cover the interval.
    """
    gtsam = _gtsam()
    check_transform("start.T_w_i", start.T_w_i)
    check_array("start.velocity_w", start.velocity_w, (3,), finite=True)
    t0 = float(start.t)
    if not t1 >= t0:
        return None, f"end time {t1:.3f} s is before start time {t0:.3f} s"
    if params is None:
        params = preintegration_params(imu, settings)
    bias = _bias(gtsam, start.accel_bias, start.gyro_bias)
    pim = gtsam.PreintegratedCombinedMeasurements(params, bias)
    if t1 > t0:
        pieces, reason = _pieces(imu, t0, t1, settings.max_sample_gap_s)
        if pieces is None:
            return None, reason
        _, acc, gyr, dts = pieces
        for a, w, dt in zip(acc, gyr, dts):  # one gtsam call per IMU sample
            if dt > 0:
                pim.integrateMeasurement(a, w, float(dt))
    state0 = gtsam.NavState(gtsam.Rot3(start.T_w_i[:3, :3]), start.T_w_i[:3, 3].copy(), start.velocity_w.copy())
    state1 = pim.predict(state0, bias)
    T_w_i1 = state1.pose().matrix()
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
    gtsam = _gtsam()
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
    """

    accel_bias: np.ndarray
    gyro_bias: np.ndarray
    velocity_w: np.ndarray
    velocity_cov: np.ndarray


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
    from scipy.spatial.transform import Rotation

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
    w_r = 1.0 / np.sqrt(imu.gyro_noise**2 * tau + 2 * settings.pose_sigma_rad**2)
    A = (Hr_g * w_r[:, None, None]).reshape(-1, 3)
    y = (r * w_r[:, None]).reshape(-1)
    P = np.eye(3) / settings.gyro_bias_prior_sigma**2
    db_g = np.linalg.solve(A.T @ A + P, A.T @ y)
    # velocity at t0 (in the IMU frame at t0) and accelerometer bias from the positions
    e_p = (T[1:, :3, 3] - p0 - 0.5 * np.outer(tau**2, g)) @ R0 - dp - Hp_g @ db_g  # (K-1, 3)
    w_p = 1.0 / np.sqrt(imu.accel_noise**2 * tau**3 / 3.0 + 2 * settings.pose_sigma_m**2)
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
    return WindowFit(b_a0 + db_a, b_g0 + db_g, v_last, 0.5 * (cov_v + cov_v.T))


def adjoint(T) -> np.ndarray:
    """(6, 6) adjoint of the rigid transform ``T: (4, 4)`` in (rotation, translation) order."""
    T = check_transform("T", T)
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, :3] = tx @ R
    A[3:, 3:] = R
    return A


def gravity_aligned_rotation(mean_accel, gravity_w) -> np.ndarray:
    """(3, 3) ``R_w_i`` such that the IMU reading ``mean_accel`` (3,) m/s^2 opposes ``gravity_w`` (3,) m/s^2.

    The yaw is arbitrary (the minimal rotation between the two directions).
    """
    a = check_array("mean_accel", mean_accel, (3,), finite=True)
    g = check_array("gravity_w", gravity_w, (3,), finite=True)
    up_i = a / np.linalg.norm(a)
    up_w = -g / np.linalg.norm(g)
    from scipy.spatial.transform import Rotation

    rot, _ = Rotation.align_vectors(up_w[None, :], up_i[None, :])
    return rot.as_matrix()


class ImuPoseSource:
    """Relative poses between a keyframe and a later frame from IMU preintegration.

    Stateful: every integrated frame's end state is kept (the one with the smallest
    velocity covariance per frame) and serves as the "previous estimate" when a later
    keyframe lacks a dataset velocity (or a pose).

    Args:
        imu: the sequence's IMU samples (with ``T_c_i``).
        sequence: the sequence (optional): its past poses feed the bias fit and the
            two-pose velocities of the keyframes.
        settings: see :class:`ImuPoseSettings`.
    """

    name = "imu"

    def __init__(self, imu: ImuData, sequence=None, settings: ImuPoseSettings = ImuPoseSettings()):
        if imu is None:
            raise InputError("sequence has no IMU")
        self.imu = imu
        self.sequence = sequence
        self.settings = settings
        self.T_c_i = check_transform("imu.T_c_i", imu.T_c_i)
        self.T_i_c = invert_transform(self.T_c_i)
        self._params = preintegration_params(imu, settings)
        self._estimates: dict[int, NavEstimate] = {}
        self._fits: dict[int, WindowFit | None] = {}
        self._imu_rate_hz = (len(imu.t) - 1) / (imu.t[-1] - imu.t[0]) if len(imu.t) > 1 else 0.0
        #: navigation state used for the keyframe of the last successful call (diagnostics)
        self.last_start: NavEstimate | None = None

    @classmethod
    def for_sequence(cls, sequence, settings: ImuPoseSettings = ImuPoseSettings()) -> "ImuPoseSource":
        """Pose source for ``sequence``. Raises :class:`InputError` "sequence has no IMU" without IMU samples."""
        if getattr(sequence, "imu", None) is None:
            why = getattr(sequence, "imu_missing_reason", "")
            raise InputError(f"{getattr(sequence, 'root', sequence)}: sequence has no IMU, so --poses imu is not "
                             f"possible{' (' + why + ')' if why else ''}; use --poses gt")
        return cls(sequence.imu, sequence, settings)

    # ------------------------------------------------------------------ state at a keyframe
    def _latest_estimate_before(self, t: float) -> NavEstimate | None:
        best = None
        for e in self._estimates.values():
            if e.t <= t and (best is None or e.t > best.t):
                best = e
        return best

    def _static_start(self, t: float) -> NavEstimate:
        imu = self.imu
        sel = (imu.t >= imu.t[0]) & (imu.t <= imu.t[0] + self.settings.static_window_s)
        mean_acc = imu.accel[sel].mean(axis=0) - np.asarray(self.settings.accel_bias)
        T = np.eye(4)
        T[:3, :3] = gravity_aligned_rotation(mean_acc, imu.gravity_w)
        return NavEstimate(t, T, np.zeros(3), np.eye(3) * self.settings.given_velocity_sigma**2, "static", "static",
                           np.asarray(self.settings.accel_bias, float), np.asarray(self.settings.gyro_bias, float))

    def _chained_estimate(self, frame: Frame) -> NavEstimate | None:
        """This source's own estimate at ``frame``: stored, or propagated from the latest earlier one."""
        est = self._estimates.get(frame.index)
        if est is not None and abs(est.t - frame.timestamp) <= 1e-9:
            return est
        prev = self._latest_estimate_before(frame.timestamp)
        if prev is None or frame.timestamp - prev.t > self.settings.max_interval_s:
            return None
        res, _ = integrate_interval(self.imu, prev, frame.timestamp, self._params, self.settings)
        return None if res is None else res.end

    def _two_pose_velocity(self, frame: Frame, T_w_i: np.ndarray, other_index: int, accel_bias, gyro_bias):
        """Velocity at ``frame`` from its pose, a neighbouring frame's pose and the IMU between them.

        With ``a`` the earlier and ``b`` the later frame: ``p_b = p_a + v_a dt + g dt^2 / 2
        + R_a dp`` gives ``v_a``, and ``v_b = v_a + g dt + R_a dv`` (exact up to IMU noise
        and bias, unlike a plain finite difference). Returns ``(v (3,), cov (3, 3))`` or None.
        """
        seq = self.sequence
        if seq is None or not 0 <= other_index < len(seq):
            return None
        other = seq[other_index]
        if other.T_w_c is None:
            return None
        T_w_o = check_transform("frame.T_w_c", other.T_w_c) @ self.T_c_i
        (t_a, T_a), (t_b, T_b) = sorted([(frame.timestamp, T_w_i), (other.timestamp, T_w_o)], key=lambda x: x[0])
        dt = t_b - t_a
        if not 0 < dt <= self.settings.max_interval_s:
            return None
        start = NavEstimate(t_a, T_a, np.zeros(3), np.zeros((3, 3)), "sequence", "unknown",
                            np.asarray(accel_bias, float), np.asarray(gyro_bias, float))
        res, _ = integrate_interval(self.imu, start, t_b, self._params, self.settings)
        if res is None:
            return None
        v_a = (T_b[:3, 3] - res.end.T_w_i[:3, 3]) / dt
        R = T_a[:3, :3]
        C = res.preintegration_cov[3:9, 3:9]  # (delta p, delta v), earlier IMU frame
        if other.timestamp > frame.timestamp:  # frame is a
            J = np.hstack([-np.eye(3) / dt, np.zeros((3, 3))])
            v = v_a
        else:  # frame is b
            J = np.hstack([-np.eye(3) / dt, np.eye(3)])
            v = res.end.velocity_w + v_a
        cov = R @ J @ C @ J.T @ R.T
        return v, 0.5 * (cov + cov.T)

    def _window_fit(self, frame: Frame) -> WindowFit | None:
        """Biases and velocity fitted to the sequence's poses of the window ending at ``frame`` (cached)."""
        s = self.settings
        if (self.sequence is None or s.bias_window_s <= 0 or frame.T_w_c is None
                or self._imu_rate_hz < s.min_fit_imu_rate_hz):
            return None
        if frame.index in self._fits:
            return self._fits[frame.index]
        frames = [frame]
        j = frame.index - 1
        while j >= 0:
            f = self.sequence[j]
            if frame.timestamp - f.timestamp > s.bias_window_s:
                break
            if f.T_w_c is not None and f.timestamp < frames[-1].timestamp:
                frames.append(f)
            j -= 1
        fit = None
        if len(frames) >= max(3, s.min_window_frames):
            frames.reverse()
            fit = fit_window(self.imu, self._params, np.array([f.timestamp for f in frames]),
                             np.stack([f.T_w_c @ self.T_c_i for f in frames]), s)
        self._fits[frame.index] = fit
        return fit

    def state_at(self, frame: Frame) -> tuple[NavEstimate | None, str]:
        """Navigation state of ``frame`` following the documented order; ``(None, reason)`` if none."""
        s = self.settings
        prior_a, prior_g = np.asarray(s.accel_bias, float), np.asarray(s.gyro_bias, float)
        est = None
        if frame.T_w_c is not None:
            T_w_i = check_transform("frame.T_w_c", frame.T_w_c) @ self.T_c_i
            pose_source = "sequence"
        else:
            est = self._chained_estimate(frame)
            if est is not None:
                T_w_i, pose_source = est.T_w_i, "estimate"
            elif s.assume_static_start and not self._estimates:
                return self._static_start(frame.timestamp), ""
            else:
                return None, "keyframe has no pose and no earlier IMU estimate to propagate"

        fit = self._window_fit(frame) if pose_source == "sequence" else None
        if fit is not None:
            b_a, b_g = fit.accel_bias, fit.gyro_bias
        elif est is not None:
            b_a, b_g = est.accel_bias, est.gyro_bias
        else:
            b_a, b_g = prior_a, prior_g

        def state(v, cov, source):
            return NavEstimate(frame.timestamp, T_w_i, np.asarray(v, float), cov, pose_source, source, b_a, b_g), ""

        if frame.velocity_w is not None:
            v = check_array("frame.velocity_w", frame.velocity_w, (3,), finite=True)
            return state(v, np.eye(3) * s.given_velocity_sigma**2, "dataset")
        if pose_source == "sequence":
            got = self._two_pose_velocity(frame, T_w_i, frame.index - 1, b_a, b_g)
            if got is not None:
                return state(got[0], got[1], "previous_interval")
            if fit is not None:
                return state(fit.velocity_w, fit.velocity_cov, "window_fit")
            est = self._chained_estimate(frame)
        if est is not None:
            return state(est.velocity_w, est.velocity_cov, "estimate")
        if pose_source == "sequence":
            got = self._two_pose_velocity(frame, T_w_i, frame.index + 1, b_a, b_g)
            if got is not None:
                return state(got[0], got[1], "finite_difference")
        if s.assume_static_start and not self._estimates:
            return state(np.zeros(3), np.eye(3) * s.given_velocity_sigma**2, "static")
        return None, "no velocity for the keyframe (none in the dataset, no estimate, no neighbouring poses)"

    # ------------------------------------------------------------------ the PoseSource API
    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        """Relative pose ``T_kf_cur`` (current camera to keyframe camera) with its (6, 6) covariance."""
        dt = current.timestamp - keyframe.timestamp
        if dt < 0:
            return RelativePose(None, ok=False, reason="current frame is older than the keyframe")
        if dt > self.settings.max_interval_s:
            return RelativePose(None, ok=False, reason=(
                f"IMU interval {dt:.2f} s exceeds max_interval_s={self.settings.max_interval_s}"))
        start, reason = self.state_at(keyframe)
        if start is None:
            return RelativePose(None, ok=False, reason=reason)
        res, reason = integrate_interval(self.imu, start, current.timestamp, self._params, self.settings)
        if res is None:
            return RelativePose(None, ok=False, reason=reason)
        self.last_start = start
        old = self._estimates.get(current.index)
        if old is None or np.trace(res.end.velocity_cov) < np.trace(old.velocity_cov) or abs(old.t - res.end.t) > 1e-9:
            self._estimates[current.index] = res.end
        if keyframe.index not in self._estimates:
            self._estimates[keyframe.index] = start
        horizon = current.timestamp - 2.0 * self.settings.max_interval_s
        for k in [k for k, e in self._estimates.items() if e.t < horizon]:
            del self._estimates[k]
        for k in [k for k in self._fits if k < keyframe.index - 1000]:
            del self._fits[k]
        T_kf_cur = self.T_c_i @ res.T_i0_i1 @ self.T_i_c
        A = adjoint(self.T_c_i)
        cov = A @ res.covariance @ A.T
        return RelativePose(T_kf_cur, 0.5 * (cov + cov.T))
