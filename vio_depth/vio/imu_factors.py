"""IMU factors between the keyframes of the landmark window (its
:class:`~vio_depth.landmarks.MotionFactorSource`).

Every keyframe ``f`` of the window has, besides its camera pose ``X(f)`` (what the
projection factors see), three keys added here: the IMU pose ``I(f)``, the IMU velocity
``V(f)`` (world, m/s) and the biases ``B(f)`` (``gtsam.imuBias.ConstantBias``). Between two
consecutive keyframes:

* a ``gtsam.CombinedImuFactor`` on ``I, V, B`` of both (preintegration of the samples
  between their timestamps, bias random walk included);
* for each keyframe a stiff ``BetweenFactorPose3(X(f), I(f), T_c_i)``: the camera and the IMU
  are rigidly mounted. (gtsam's ``body_P_sensor`` would put the IMU factor on the camera
  pose directly, but it leaves out the lever arm's angular-acceleration term: on the
  street sample, 1.3 m from the IMU, that is up to 0.6 m/s^2 during the turn.)

The first keyframe of a window gets the priors of the initialisation (its
:class:`KeyframeState`, handed to :meth:`ImuFactors.factors` as ``initial``): its yaw and
position fix the gauge (they are unobservable), its roll and pitch, velocity and biases
carry the initialisation's uncertainty. The window marginalises these factors with the
keyframe into linear marginal factors (``keep_marginals``; :mod:`vio_depth.landmarks.marginalisation`);
after each marginalisation the new oldest keyframe gets a gauge prior on its yaw and
position (:meth:`ImuFactors.after_marginalisation`): without it the window drifted by
degrees and decimetres along these unobservable directions at every update (room sample),
and the Levenberg-Marquardt steps with it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError, NumericalError
from vio_core.geometry import adjoint, invert_transform

from ..frame import ImuData
from ..landmarks import KeyframeInput, MotionFactors
from ..poses import preintegrate, preintegration_params
from .settings import VioSettings

#: stiffness of the camera-IMU mounting factor (rad, m)
_MOUNT_SIGMA = 1e-5


def imu_key(frame_id: int) -> int:
    """gtsam key of the IMU pose of keyframe ``frame_id``."""
    import gtsam

    return gtsam.symbol("i", int(frame_id))


def velocity_key(frame_id: int) -> int:
    import gtsam

    return gtsam.symbol("v", int(frame_id))


def bias_key(frame_id: int) -> int:
    import gtsam

    return gtsam.symbol("b", int(frame_id))


@dataclass(frozen=True)
class KeyframeState:
    """Navigation state of a keyframe, with the 1-sigma of its prior when it starts a window.

    Attributes:
        t: seconds.
        T_w_i: (4, 4) IMU-to-world pose, metres.
        velocity_w: (3,) m/s, IMU velocity in the world.
        accel_bias: (3,) m/s^2. gyro_bias: (3,) rad/s.
        tilt_sigma: rad, roll and pitch. yaw_sigma: rad. position_sigma: m.
        velocity_sigma: m/s. accel_bias_sigma: m/s^2. gyro_bias_sigma: rad/s.
    """

    t: float
    T_w_i: np.ndarray
    velocity_w: np.ndarray
    accel_bias: np.ndarray
    gyro_bias: np.ndarray
    tilt_sigma: float = 0.02
    yaw_sigma: float = 1e-3
    position_sigma: float = 1e-3
    velocity_sigma: float = 0.1
    accel_bias_sigma: float = 0.1
    gyro_bias_sigma: float = 0.01

    def __post_init__(self):
        check_transform("T_w_i", self.T_w_i)
        for name in ("velocity_w", "accel_bias", "gyro_bias"):
            check_array(name, getattr(self, name), (3,), finite=True)

    def pose_covariance(self) -> np.ndarray:
        """(6, 6) prior covariance of ``T_w_i`` in gtsam's body tangent (rotation first):
        roll/pitch ``tilt_sigma`` and yaw ``yaw_sigma`` about the world axes, position
        ``position_sigma``."""
        R = self.T_w_i[:3, :3]
        C = np.zeros((6, 6))
        C[:3, :3] = R.T @ np.diag([self.tilt_sigma**2, self.tilt_sigma**2, self.yaw_sigma**2]) @ R
        C[3:, 3:] = np.eye(3) * self.position_sigma**2
        return C


class ImuFactors:
    """The window's motion factor source for the IMU (module docstring).

    Args:
        imu: the IMU samples (with ``T_c_i``); :meth:`update_samples` extends them.
        settings: :class:`~vio_depth.vio.VioSettings` (``imu``: noise scales, sample gaps).
    """

    #: every keyframe's pose comes from here (the IMU state), the frames' priors are IMU predictions
    provides_poses = True
    #: the IMU chain's information is kept when a keyframe is marginalised
    keep_marginals = True

    def __init__(self, imu: ImuData, settings: VioSettings):
        self.imu = imu
        self.settings = settings
        self.T_c_i = check_transform("imu.T_c_i", imu.T_c_i)
        self.T_i_c = invert_transform(self.T_c_i)
        self._A_c_i = adjoint(self.T_c_i)
        self.params = preintegration_params(imu, settings.imu)

    def update_samples(self, imu: ImuData) -> None:
        """Use ``imu`` (the samples so far plus newer ones) from now on; same calibration."""
        if not np.allclose(imu.T_c_i, self.imu.T_c_i) or imu.gravity_w != self.imu.gravity_w:
            raise InputError("update_samples: the IMU calibration changed")
        self.imu = imu

    def samples_between(self, t0: float, t1: float) -> ImuData:
        """The samples from ``t0`` to ``t1`` seconds and two beyond each end: all that a copy of
        these factors needs for a keyframe interval (e.g. the landmark window's in a worker
        process, :mod:`vio_depth.landmarks.backend`, which gets them by :meth:`update_samples`)."""
        t = self.imu.t
        i0 = max(int(np.searchsorted(t, t0, "right")) - 2, 0)
        i1 = min(int(np.searchsorted(t, t1, "left")) + 2, len(t))
        return replace(self.imu, t=t[i0:i1], gyro=self.imu.gyro[i0:i1], accel=self.imu.accel[i0:i1])

    # ------------------------------------------------------------------ states
    def state_of(self, estimate, frame_id: int, t: float) -> KeyframeState:
        """The navigation state of keyframe ``frame_id`` in a window estimate (``gtsam.Values``).

        Raises:
            NumericalError: the estimate is not finite.
        """
        T = estimate.atPose3(imu_key(frame_id)).matrix()
        v = np.asarray(estimate.atVector(velocity_key(frame_id)), float).reshape(3)
        b = estimate.atConstantBias(bias_key(frame_id))
        a, g = np.asarray(b.accelerometer(), float).reshape(3), np.asarray(b.gyroscope(), float).reshape(3)
        if not all(np.all(np.isfinite(x)) for x in (T, v, a, g)):
            raise NumericalError(f"vio: the window's state of keyframe {frame_id} is not finite")
        return KeyframeState(t, T, v, a, g)

    def preintegrate(self, state: KeyframeState, t1: float):
        """``(pim, "")`` from ``state.t`` to ``t1`` with the state's biases, or ``(None, reason)``."""
        return preintegrate(self.imu, state.t, t1, self.params, state.accel_bias, state.gyro_bias,
                            self.settings.imu.max_sample_gap_s)

    def predict(self, state: KeyframeState, t1: float) -> tuple[KeyframeState | None, np.ndarray | None, str]:
        """IMU prediction from ``state`` to ``t1`` seconds.

        Returns:
            ``(state at t1, (6, 6) covariance of the camera pose relative to the start (right
            perturbation, rotation first; preintegration noise only), "")`` or
            ``(None, None, reason)``.
        """
        pim, reason = self.preintegrate(state, t1)
        if pim is None:
            return None, None, reason
        return self.predict_with(pim, state, t1)

    def predict_camera(self, state: KeyframeState, t1: float) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        """``(T_w_c (4, 4), (6, 6) covariance, "")`` of the camera at ``t1`` seconds by IMU
        prediction from ``state``, or ``(None, None, why)``. The covariance: the preintegration
        noise, and the state's velocity and biases (not in the window's pose marginals) through the
        elapsed time (``predict_gyro_sigma``, ``predict_velocity_sigma``)."""
        s = self.settings
        pred, C, reason = self.predict(state, t1)
        if pred is None:
            return None, None, reason
        dt = t1 - state.t
        C = C + np.diag([(s.predict_gyro_sigma * dt) ** 2] * 3 + [(s.predict_velocity_sigma * dt) ** 2] * 3)
        return pred.T_w_i @ self.T_i_c, C, ""

    def predict_with(self, pim, state: KeyframeState, t1: float, covariance: bool = True):
        """:meth:`predict` with a preintegration ``pim`` from ``state.t`` to ``t1`` that was
        integrated at other biases (gtsam corrects it to ``state``'s biases to first order):
        a prediction repeated from an updated state without integrating the samples again.
        ``covariance=False``: the covariance is not computed (None)."""
        import gtsam

        bias = gtsam.imuBias.ConstantBias(state.accel_bias, state.gyro_bias)
        nav = pim.predict(gtsam.NavState(gtsam.Rot3(state.T_w_i[:3, :3]), state.T_w_i[:3, 3].copy(),
                                         state.velocity_w.copy()), bias)
        T = nav.pose().matrix()
        v = np.asarray(nav.velocity(), float).reshape(3)
        if not (np.all(np.isfinite(T)) and np.all(np.isfinite(v))):
            return None, None, f"IMU prediction to {t1:.3f} s is not finite"
        end = KeyframeState(t1, T, v, state.accel_bias, state.gyro_bias)
        if not covariance:
            return end, None, ""
        C = np.asarray(pim.preintMeasCov())[:6, :6] if t1 > state.t else np.zeros((6, 6))
        J = np.eye(6)
        R_rel = state.T_w_i[:3, :3].T @ T[:3, :3]
        J[3:, 3:] = R_rel.T  # translation error: start frame -> end frame (right perturbation)
        C = J @ C @ J.T
        A = self._A_c_i  # IMU pose error -> camera pose error
        C = A @ C @ A.T
        return end, 0.5 * (C + C.T), ""

    # ------------------------------------------------------------------ MotionFactorSource
    def after_marginalisation(self, oldest: int, estimate):
        """A gauge prior on the window's oldest keyframe: its yaw and position stay where they
        are (they are unobservable: only the first keyframe's prior, thinned by every
        marginalisation, held them); roll and pitch stay free (gravity observes them)."""
        import gtsam

        T = estimate.atPose3(imu_key(oldest)).matrix()
        s = self.settings
        gauge = KeyframeState(0.0, T, np.zeros(3), np.zeros(3), np.zeros(3), tilt_sigma=1.0,
                              yaw_sigma=s.gauge_yaw_sigma_rad, position_sigma=s.gauge_sigma_m)
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.PriorFactorPose3(imu_key(oldest), gtsam.Pose3(T),
                                         gtsam.noiseModel.Gaussian.Covariance(gauge.pose_covariance())))
        return graph

    def extra_keys(self, frame_id: int) -> list[int]:
        return [imu_key(frame_id), velocity_key(frame_id), bias_key(frame_id)]

    def factors(self, previous: KeyframeInput | None, current: KeyframeInput, estimate,
                initial: KeyframeState | None = None) -> MotionFactors:
        """Factors and initial values for keyframe ``current`` (see the module docstring).

        Args:
            previous: the window's newest keyframe, or None for its first keyframe.
            current: the new keyframe.
            estimate: the window's ``gtsam.Values``.
            initial: ``current``'s state from an initialisation: the first keyframe's prior
                (required), another keyframe's initial value (else the IMU prediction from
                ``previous``).

        Returns:
            :class:`~vio_depth.landmarks.MotionFactors`; failed (with the reason) when the IMU
            cannot link ``previous`` and ``current`` (e.g. a gap in the samples).

        Raises:
            InputError: no ``initial`` state (at ``current``'s time) for a first keyframe.
        """
        import gtsam
        from gtsam.symbol_shorthand import X

        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        f = int(current.frame_id)
        guess = initial
        if previous is None:
            start = guess
            if start is None or abs(start.t - current.timestamp) > 1e-6:
                raise InputError(f"vio: no initial state for the first keyframe {f} of the window")
            graph.add(gtsam.PriorFactorPose3(imu_key(f), gtsam.Pose3(start.T_w_i),
                                             gtsam.noiseModel.Gaussian.Covariance(start.pose_covariance())))
            graph.add(gtsam.PriorFactorVector(velocity_key(f), start.velocity_w,
                                              gtsam.noiseModel.Isotropic.Sigma(3, start.velocity_sigma)))
            sig = np.r_[[start.accel_bias_sigma] * 3, [start.gyro_bias_sigma] * 3]
            graph.add(gtsam.PriorFactorConstantBias(bias_key(f), gtsam.imuBias.ConstantBias(start.accel_bias,
                                                                                          start.gyro_bias),
                                                    gtsam.noiseModel.Diagonal.Sigmas(sig)))
            state = start
        else:
            p = int(previous.frame_id)
            prev_state = self.state_of(estimate, p, previous.timestamp)
            pim, reason = self.preintegrate(prev_state, current.timestamp)
            if pim is None:
                return MotionFactors.failed(f"vio: no IMU factor between keyframes {p} and {f}: {reason}")
            graph.add(gtsam.CombinedImuFactor(imu_key(p), velocity_key(p), imu_key(f), velocity_key(f),
                                              bias_key(p), bias_key(f), pim))
            if guess is not None:
                state = guess
            else:
                state, _, reason = self.predict(prev_state, current.timestamp)
                if state is None:
                    return MotionFactors.failed(f"vio: no IMU prediction for keyframe {f}: {reason}")
        graph.add(gtsam.BetweenFactorPose3(X(f), imu_key(f), gtsam.Pose3(self.T_c_i),
                                           gtsam.noiseModel.Isotropic.Sigma(6, _MOUNT_SIGMA)))
        values.insert(X(f), gtsam.Pose3(state.T_w_i @ self.T_i_c))
        values.insert(imu_key(f), gtsam.Pose3(state.T_w_i))
        values.insert(velocity_key(f), np.asarray(state.velocity_w, float))
        values.insert(bias_key(f), gtsam.imuBias.ConstantBias(np.asarray(state.accel_bias, float),
                                                               np.asarray(state.gyro_bias, float)))
        return MotionFactors(graph, values)
