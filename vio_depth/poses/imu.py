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
(rotation, position) plus the keyframe velocity's covariance times ``dt^2`` plus the bias
estimate's covariance mapped through the preintegration's bias Jacobian, all mapped to
the camera relative pose. Convention (gtsam ``Pose3``): the true pose is
``T_kf_cur @ Exp([omega, nu])`` with ``omega`` rad (rotation first) and ``nu`` metres,
both in the *current* camera frame. It does not include the keyframe orientation's error
(zero with sequence poses).

Calibration (docs/benchmarks.md, "IMU propagation and covariance"): with only the
datasheet white noise (:meth:`ImuPoseSettings.uncalibrated`) the covariance was 15-30x
too small in sigma on the real EuRoC V1_01 stream (translation NEES medians 275-1030 for
0.25-1 s), because (1) a two-pose velocity's covariance left out the poses' own noise,
(2) the bias estimate's error was left out -- and a 2 s window fit on a real IMU scatters
7-30x more than its least-squares covariance says (scale-factor / misalignment errors,
vibration, drift) -- and (3) the real accelerometer on a flying MAV is noisier than its
datasheet. The defaults fix (1) (``velocity_pose_sigma_m``) and (2) (``bias_covariance``,
the fit's covariance grown to the scatter of recent fits); (3) is the pose preset
``imu_real_mav`` (accelerometer noise x10, calibrated on the first half of the EuRoC
stream and checked on the second).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError
from vio_core.geometry import adjoint, invert_transform

from ..frame import Frame, ImuData
from .base import RelativePose
from .imu_state import ImuPoseSettings, NavEstimate
from .preintegration import (
    WindowFit,
    fit_window,
    gravity_aligned_rotation,
    integrate_interval,
    preintegration_params,
)


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
        self._bias_history: list[tuple[float, np.ndarray]] = []  # (t, (accel, gyro) bias) of past window fits
        self._imu_rate_hz = (len(imu.t) - 1) / (imu.t[-1] - imu.t[0]) if len(imu.t) > 1 else 0.0
        #: navigation state used for the keyframe of the last successful call (diagnostics)
        self.last_start: NavEstimate | None = None

    def update_samples(self, imu: ImuData) -> None:
        """Use ``imu`` from now on: the samples so far plus newer ones (streaming input).

        The calibration (``T_c_i``, noise densities, gravity) must be the same.
        """
        if not np.allclose(imu.T_c_i, self.imu.T_c_i) or imu.gravity_w != self.imu.gravity_w:
            raise InputError("update_samples: the IMU calibration changed")
        self.imu = imu
        self._imu_rate_hz = (len(imu.t) - 1) / (imu.t[-1] - imu.t[0]) if len(imu.t) > 1 else 0.0

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
                           np.asarray(self.settings.accel_bias, float), np.asarray(self.settings.gyro_bias, float),
                           self._prior_bias_cov())

    def _prior_bias_cov(self) -> np.ndarray:
        """(6, 6) covariance of the prior biases (accelerometer m/s^2, gyroscope rad/s)."""
        s = self.settings
        return np.diag([s.accel_bias_prior_sigma**2] * 3 + [s.gyro_bias_prior_sigma**2] * 3)

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
                            np.asarray(accel_bias, float), np.asarray(gyro_bias, float))  # bias error: see state_at
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
        if self.settings.pose_noise_in_velocity:  # both poses' noise enters (p_b - p_a) / dt
            cov = cov + np.eye(3) * 2.0 * self.settings.velocity_pose_sigma_m**2 / dt**2
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
        if fit is not None and s.bias_covariance and s.bias_scatter_window_s > 0:
            fit = self._with_bias_scatter(frame.timestamp, fit)
        self._fits[frame.index] = fit
        return fit

    def _with_bias_scatter(self, t: float, fit: WindowFit) -> WindowFit:
        """``fit`` with its bias covariance grown to the scatter of the window fits of the
        last ``bias_scatter_window_s`` seconds (this one included), per bias component.

        The least-squares covariance of one fit only knows the assumed white noise; the
        scatter of successive fits also holds what that model misses (on a real IMU:
        scale-factor and misalignment errors, vibration, drift), and stays small where the
        model holds (the SIMULATED samples). Needs 3 fits; only past fits are used.
        """
        lo = t - self.settings.bias_scatter_window_s
        self._bias_history = [(tb, b) for tb, b in self._bias_history if lo <= tb < t]
        self._bias_history.append((t, np.concatenate([fit.accel_bias, fit.gyro_bias])))
        if len(self._bias_history) < 3:
            return fit
        scatter = np.cov(np.array([b for _, b in self._bias_history]).T)
        # the scatter already holds the fits' own noise: take the larger of the two per bias component
        grow = np.sqrt(np.maximum(np.diag(scatter) / np.maximum(np.diag(fit.bias_cov), 1e-30), 1.0))
        return replace(fit, bias_cov=fit.bias_cov * np.outer(grow, grow))

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
            b_a, b_g, b_cov = fit.accel_bias, fit.gyro_bias, fit.bias_cov
        elif est is not None:
            b_a, b_g, b_cov = est.accel_bias, est.gyro_bias, est.bias_cov
        else:
            b_a, b_g, b_cov = prior_a, prior_g, self._prior_bias_cov()

        def state(v, cov, source):
            return NavEstimate(frame.timestamp, T_w_i, np.asarray(v, float), cov, pose_source, source, b_a, b_g,
                               b_cov), ""

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
