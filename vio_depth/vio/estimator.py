"""The visual-inertial odometry: one frame at a time, initialising, tracking, re-initialising.

States (:class:`VioStatus`), per frame:

* ``initialising``: :class:`~vio_depth.vio.initializer.Initializer` is waiting for a still
  start or for enough keyframes and excitation (the frame has **no pose**, with the reason);
* ``tracking``: the landmark window (:class:`~vio_depth.landmarks.LandmarkEstimator`) with
  IMU factors (:class:`~vio_depth.vio.imu_factors.ImuFactors`) between its keyframes. Each
  frame's pose prior is the IMU prediction from the newest keyframe's state (pose,
  velocity, biases); the window matches the frame with its keyframes, refines its pose
  against the landmarks (a keyframe: the whole window, Levenberg-Marquardt over poses,
  velocities, biases and landmarks; the oldest keyframe is marginalised beyond
  ``window_keyframes``: a fixed-lag smoother with bounded memory);
* ``converging``: tracking, but the window does not know the metric scale to
  ``max_scale_sigma`` yet (e.g. just after a start with little excitation): the frame has
  **no pose** now (it keeps one in the history, for the offline backward pass);
* ``still``: tracking, and the IMU and the images say the camera rests: the frame takes the
  newest keyframe's pose (a zero-velocity update in its simplest form, as OpenVINS detects
  rest from the IMU and the feature motion); the window is not updated, so a resting
  camera neither drifts on the IMU alone nor loses tracking for lack of parallax;
* ``imu_only``: tracking, but the frame's pose could not be refined against landmarks
  (too few): the IMU prediction is used, trusted for at most ``max_imu_only_s``;
* ``lost``: the estimate diverged (speed, biases beyond plausible bounds) or had no visual
  support for longer than ``max_imu_only_s``: the frame has **no pose**, the window is
  dropped and the initialisation starts again (a new session: poses of different
  sessions are never related).

Poses kept (:attr:`VioEstimator.history`): keyframes follow the window's latest estimate
until they are marginalised. A frame between two keyframes is posed when it is processed
(against the landmarks) and again, after every window update while both keyframes are in
the window, by the IMU between them: the prediction from the earlier keyframe's state
with its mismatch at the later keyframe spread linearly in time (a bridge). The frames of
an initialisation get their poses that way only after it succeeded (retroactively): the
offline backward pass of a run can use them.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from matchers import Features, Matcher
from vio_core.camera import Camera
from vio_core.errors import InputError
from vio_core.geometry import invert_transform

from ..frame import ImuData
from ..landmarks import LandmarkEstimator
from ..poses import VioSettings, adjoint, detect_still_interval, preintegrate
from .history import PoseHistory
from .imu_factors import ImuFactors, KeyframeState
from .initializer import Initializer, InitResult
from .landmark_feed import KEPT_FRAMES, LandmarkLog, OdometryLandmarks, relative_scale_sigma
from .matching import EpipolarGatedMatcher, rotation_free_flow

log = logging.getLogger(__name__)


class VioStatus(str, enum.Enum):
    """The odometry's state at a frame (module docstring)."""

    INITIALISING = "initialising"
    CONVERGING = "converging"
    TRACKING = "tracking"
    STILL = "still"
    IMU_ONLY = "imu_only"
    LOST = "lost"


@dataclass(frozen=True)
class VioFrame:
    """The odometry's result for one frame.

    Attributes:
        frame_id: the frame. status: :class:`VioStatus`. reason: why no pose / what is special.
        T_w_c: (4, 4) camera-to-world, metres (None without a pose).
        covariance: (6, 6) relative to the newest keyframe (right perturbation), or None.
        keyframe: the frame became a keyframe of the window.
        landmarks: landmarks the frame's pose was refined against.
        velocity_w: (3,) m/s IMU velocity of the newest keyframe. accel_bias / gyro_bias: its biases.
        initialised: "static" / "dynamic" on the frame that completed an initialisation.
    """

    frame_id: int
    status: VioStatus
    reason: str = ""
    T_w_c: np.ndarray | None = None
    covariance: np.ndarray | None = None
    keyframe: bool = False
    landmarks: int = 0
    velocity_w: np.ndarray | None = None
    accel_bias: np.ndarray | None = None
    gyro_bias: np.ndarray | None = None
    initialised: str = ""

    @property
    def ok(self) -> bool:
        return self.T_w_c is not None


class VioEstimator:
    """Visual-inertial odometry over the frames of one camera (module docstring).

    Args:
        imu: the IMU samples (with ``T_c_i``, noise densities, gravity).
        matcher: matches the frames' features (the same matcher extracted them).
        settings: :class:`~vio_depth.poses.VioSettings`.
    """

    def __init__(self, imu: ImuData, matcher: Matcher, settings: VioSettings = VioSettings()):
        if imu is None:
            raise InputError("vio: no IMU samples")
        self.settings = settings
        self.matcher = matcher
        self._gate = EpipolarGatedMatcher(matcher, settings.epipolar_threshold_px)
        self.factors = ImuFactors(imu, settings)
        self.initializer = Initializer(imu, self._gate, settings, self.factors.params)
        self.history = PoseHistory(settings.history_frames)
        self.landmarks: LandmarkEstimator | None = None
        self.session = 0
        self._times: dict[int, float] = {}
        self._last_visual_t = -np.inf
        self._last_id: int | None = None
        # (id, t, features) of the previous frame, and the last frame that got a pose (rest tests)
        self._previous: tuple[int, float, Features] | None = None
        self._posed_previous: int | None = None
        #: the landmark window's last update and the last initialisation (diagnostics)
        self.last_update = None
        self.last_init: InitResult | None = None
        # frames posed again after every window update, between the keyframes around them:
        # (frame, t, keyframe before, keyframe after), and those still waiting for the keyframe after
        self._bridged: list[tuple[int, float, int, int]] = []
        self._unbridged: list[tuple[int, float, int]] = []
        #: the landmarks each tracked frame saw (``--points vio`` reads them: :meth:`frame_landmarks`)
        self.landmark_log = LandmarkLog(min(settings.history_frames, KEPT_FRAMES))

    @property
    def imu(self) -> ImuData:
        return self.factors.imu

    def update_samples(self, imu: ImuData) -> None:
        """Use ``imu`` (the samples so far plus newer ones) from now on (streaming input)."""
        self.factors.update_samples(imu)
        self.initializer.update_samples(imu)

    @property
    def tracking(self) -> bool:
        return self.landmarks is not None

    def frame_landmarks(self, frame_id: int) -> OdometryLandmarks | None:
        """The metric landmarks the odometry saw in frame ``frame_id``, or None.

        Every frame the landmark window tracked (and the keyframes of an initialisation)
        keeps them for the last ``KEPT_FRAMES`` (256) frames: ``points.uv`` (N, 2) raw pixels,
        ``points.depth`` (N,) metres, ``points.sigma_depth`` (N,) metres from the landmarks'
        marginal covariances and the frame's pose covariance, and the window's relative
        scale 1-sigma at that moment (:class:`~vio_depth.vio.landmark_feed.OdometryLandmarks`).
        Frames at rest (``still``), initialising or lost have none.
        """
        return self.landmark_log.get(frame_id)

    def _scale_sigma(self) -> float:
        return relative_scale_sigma(*self.history.window_span_sigma())

    # ------------------------------------------------------------------ helpers
    def _newest_state(self) -> KeyframeState:
        w = self.landmarks.window
        f = w.keyframe_ids[-1]
        return self.factors.state_of(w.estimate, f, self._times[f])

    def _sync_history(self) -> None:
        w = self.landmarks.window
        ids = w.keyframe_ids
        self.history.update_keyframes(self.session, ids, np.stack([w.pose(f) for f in ids]), w.joint_covariance(ids))
        keep = []
        for f, t, a, b in self._bridged:
            if a in ids and b in ids:
                T, C = self._bridge(t, a, b)
                if T is not None:  # anchored to the later keyframe, which stays in the window longer
                    self.history.add_frame(f, self.session, b, T, C)
                keep.append((f, t, a, b))
        self._bridged = keep

    def _health(self) -> str:
        """Why the newest keyframe's state is implausible ("" when it is fine)."""
        s = self.settings
        st = self._newest_state()
        if not np.all(np.isfinite(st.T_w_i)):
            return "the estimate is not finite"
        speed = float(np.linalg.norm(st.velocity_w))
        if not speed <= s.max_speed_m_s:
            return f"estimated speed {speed:.1f} m/s (> {s.max_speed_m_s})"
        if not np.linalg.norm(st.accel_bias) <= s.max_accel_bias:
            return f"estimated accelerometer bias {np.linalg.norm(st.accel_bias):.2f} m/s^2 (> {s.max_accel_bias})"
        if not np.linalg.norm(st.gyro_bias) <= s.max_gyro_bias:
            return f"estimated gyroscope bias {np.linalg.norm(st.gyro_bias):.3f} rad/s (> {s.max_gyro_bias})"
        return ""

    def _lose(self, frame_id: int, reason: str) -> VioFrame:
        log.info("vio: lost at frame %d: %s", frame_id, reason)
        self.landmarks = None
        self.initializer.reset()
        self.session += 1
        return VioFrame(frame_id, VioStatus.LOST, f"odometry lost: {reason}; re-initialising")

    # ------------------------------------------------------------------ start
    def _start(self, res: InitResult) -> str:
        """Build the window from an initialisation; "" on success, else why it was refused."""
        s = self.settings
        self.session += 1
        self.landmarks = LandmarkEstimator(s.window, self._gate, self.factors)
        self.factors.start = res.states[0]
        self.factors.guesses = {k.frame_id: st for k, st in zip(res.keyframes[1:], res.states[1:])}
        T_i_c = invert_transform(self.factors.T_c_i)
        try:
            for k, st in zip(res.keyframes, res.states):
                self._times[k.frame_id] = k.t
                matches = tuple(m for m in k.matches if m.keyframe in self.landmarks.window.keyframe_ids)
                upd = self.landmarks.insert_keyframe(k.frame_id, k.t, k.camera, st.T_w_i @ T_i_c, k.features, matches)
                log.debug("vio: start keyframe %d: %d landmarks, %d observations, median residual %.2f px, "
                          "graph error %.1f -> %.1f", k.frame_id, upd.landmarks, upd.observations,
                          upd.median_residual_px, upd.lm_error_before, upd.lm_error_after)
        except (InputError, RuntimeError) as exc:
            self.landmarks = None
            return f"the window could not start: {exc}"
        self.factors.guesses = {}
        why = self._health()
        if not why and res.kind == "dynamic" and len(res.keyframes) > 1:
            w = self.landmarks.window
            p_win = np.stack([w.pose(k.frame_id)[:3, 3] for k in res.keyframes])
            p_al = np.stack([(st.T_w_i @ T_i_c)[:3, 3] for st in res.states])
            ratio = np.sum(np.linalg.norm(np.diff(p_win, axis=0), axis=1)) / max(
                np.sum(np.linalg.norm(np.diff(p_al, axis=0), axis=1)), 1e-12)
            if not abs(ratio - 1.0) <= s.init.max_scale_change:
                why = (f"the visual-inertial refinement changed the scale by {ratio - 1:+.1%} "
                       f"(> {s.init.max_scale_change:.0%})")
        if why:
            self.landmarks = None
            return why
        # the other frames of the initialisation: posed between the keyframes around them,
        # again after every window update while those keyframes are in the window
        key_t = [(k.frame_id, k.t) for k in res.keyframes]
        self._bridged, self._unbridged = [], []
        for f, t in res.frames:
            before = [k for k, kt in key_t if kt <= t]
            after = [k for k, kt in key_t if kt > t]
            if before and after:
                self._bridged.append((f, t, before[-1], after[0]))
        self._sync_history()
        self._last_visual_t = res.keyframes[-1].t
        self.landmark_log.record_window_keyframes(
            self.landmarks, [(k.frame_id, k.camera, np.asarray(k.features.keypoints, np.float64)) for k in res.keyframes],
            self._scale_sigma(), f"{res.kind} initialisation keyframe")
        return ""

    def _bridge(self, t: float, a: int, b: int):
        """Camera pose (4, 4) of a frame at ``t`` between keyframes ``a`` and ``b`` and its
        covariance (6, 6) relative to ``b``, or ``(None, None)``.

        The IMU prediction from ``a``'s state, its mismatch at ``b`` spread linearly in time
        (a bridge). Covariance: the preintegration noise from ``t`` to ``b``, plus the share
        ``(1 - s)^2`` of the relative uncertainty of ``a`` and ``b`` (``s`` the fraction of
        the interval elapsed at ``t``).
        """
        w = self.landmarks.window
        est = w.estimate
        st = self.factors.state_of(est, a, self._times[a])
        t_b = self._times[b]
        end, _, _ = self.factors.predict(st, t)
        end_b, _, _ = self.factors.predict(st, t_b)
        if end is None or end_b is None:
            return None, None
        _, C_fb, _ = self.factors.predict(end, t_b)  # noise of the camera's motion from t to b, in b
        T_b = self.factors.state_of(est, b, t_b).T_w_i
        s = (t - st.t) / max(t_b - st.t, 1e-12)
        dR = Rotation.from_matrix(T_b[:3, :3] @ end_b.T_w_i[:3, :3].T).as_rotvec()
        T = end.T_w_i.copy()
        T[:3, :3] = Rotation.from_rotvec(s * dR).as_matrix() @ T[:3, :3]
        T[:3, 3] = T[:3, 3] + s * (T_b[:3, 3] - end_b.T_w_i[:3, 3])
        T_w_f = T @ invert_transform(self.factors.T_c_i)
        T_f_b = invert_transform(T_w_f) @ w.pose(b)
        A = adjoint(T_f_b)  # (T_f_b)^-1 = T_b_f: its covariance in f from the one of T_f_b in b
        C = A @ C_fb @ A.T
        S = w.joint_covariance([a, b])
        C_ab = PoseHistory._pair_covariance(w.pose(a), w.pose(b), S, 0, 1)
        C = C + (1.0 - s) ** 2 * A @ C_ab @ A.T
        return T_w_f, 0.5 * (C + C.T)

    # ------------------------------------------------------------------ per frame
    def process(self, frame_id: int, t: float, camera: Camera, features: Features) -> VioFrame:
        """Process the next frame (ids and times increasing)."""
        out = self._process(frame_id, t, camera, features)
        self._previous = (int(frame_id), float(t), features)
        if out.T_w_c is not None or out.status == VioStatus.CONVERGING:  # posed (converging: kept in the history)
            self._posed_previous = int(frame_id)
        return out

    def _process(self, frame_id: int, t: float, camera: Camera, features: Features) -> VioFrame:
        if self._last_id is not None and frame_id <= self._last_id:
            raise InputError(f"vio: frames must come in order, got {frame_id} after {self._last_id}")
        self._last_id = int(frame_id)
        self._times[int(frame_id)] = float(t)
        self._gate.camera = camera
        if len(self._times) > 4 * self.settings.history_frames:
            for k in sorted(self._times)[: len(self._times) // 2]:
                self._times.pop(k)
        if not self.tracking:
            res = self.initializer.process(frame_id, t, camera, features)
            if not res.ok:
                return VioFrame(frame_id, VioStatus.INITIALISING, res.reason)
            why = self._start(res)
            if why:
                self.initializer.refuse(why, drop_oldest=False)
                return VioFrame(frame_id, VioStatus.INITIALISING, f"initialisation refused: {why}")
            al = res.alignment
            log.info("vio: %s initialisation at frame %d (%d keyframes%s)", res.kind, frame_id, len(res.keyframes),
                     "" if al is None else f"; scale {al.scale:.4g} +- {al.scale_sigma:.1%}, gravity error "
                                           f"{al.gravity_error:+.2f} m/s^2, excitation {al.excitation:.2f} m/s^2")
            self.last_init = res
            st = self._newest_state()
            return self._trusted(VioFrame(frame_id, VioStatus.TRACKING, f"{res.kind} initialisation",
                                          self.history.pose(frame_id), np.zeros((6, 6)), True, 0, st.velocity_w,
                                          st.accel_bias, st.gyro_bias, res.kind))
        return self._track(int(frame_id), float(t), camera, features)

    def _still_pose(self, t: float, camera: Camera, features: Features, newest: int):
        """``(T_w_c (4, 4), rotation-free flow px)`` when the camera rests at ``t``, else None.

        At rest: the IMU was still for ``init.static.min_still_s`` seconds up to ``t``, and
        the keypoints moved less than ``init.still_flow_px`` since the previous frame once
        the gyroscope's rotation is removed (a 1 px test against the newest keyframe fails
        on real rests, where the platform settles by millimetres: EuRoC V1_01 drifts 1-2 px
        over 3 s), and less than ``max_rest_flow_px`` since the newest keyframe (a slow creep
        adds up). The pose is keyframe ``newest``'s IMU position (zero velocity since it)
        with its orientation turned by the gyroscope (the keyframe's bias): a resting
        platform may still tilt.
        """
        s = self.settings
        st = s.init.static
        prev = self._previous
        if prev is None or prev[0] != self._posed_previous:
            return None  # rest continues a posed frame only
        t0 = max(float(self.imu.t[0]), t - st.min_still_s - st.window_s)
        window = self.imu.window(t0, t)
        if len(window.t) < 10:
            return None
        t_start, t_end = detect_still_interval(window, replace(st, start_s=0.0))
        if t_end - t_start < st.min_still_s - 1e-6 or t_end < t - st.window_s - 1e-6:
            return None
        state = self._newest_state()
        pim, _ = preintegrate(self.imu, state.t, t, self.factors.params, state.accel_bias, state.gyro_bias,
                              s.imu.max_sample_gap_s)
        pim_prev, _ = preintegrate(self.imu, prev[1], t, self.factors.params, state.accel_bias, state.gyro_bias,
                                   s.imu.max_sample_gap_s)
        if pim is None or pim_prev is None:
            return None
        m = self.matcher.match(features, prev[2])
        if len(m) < s.min_tracked_landmarks:
            return None
        T_i_c = invert_transform(self.factors.T_c_i)
        R_c_i = self.factors.T_c_i[:3, :3]
        R_prev_cur = R_c_i @ pim_prev.deltaRij().matrix() @ R_c_i.T  # the camera's rotation since the previous frame
        flow = rotation_free_flow(features.keypoints[m.idx_a], prev[2].keypoints[m.idx_b], camera, camera, R_prev_cur)
        if flow > s.init.still_flow_px:
            return None
        kf = self.landmarks.keyframe_features(newest)  # a slow creep adds up: bounded since the keyframe
        m_kf = None if kf is None else self.matcher.match(features, kf)
        if m_kf is None or len(m_kf) < s.min_tracked_landmarks:
            return None
        R_kf_cur = R_c_i @ pim.deltaRij().matrix() @ R_c_i.T
        creep = rotation_free_flow(features.keypoints[m_kf.idx_a], kf.keypoints[m_kf.idx_b], camera, camera, R_kf_cur)
        if creep > s.max_rest_flow_px:
            return None
        T_kf_i = np.eye(4)
        T_kf_i[:3, :3] = pim.deltaRij().matrix()  # IMU rotation since the keyframe, position unchanged
        return state.T_w_i @ T_kf_i @ T_i_c, flow

    def _still_frame(self, frame_id: int, t: float, camera: Camera, newest: int, T_w_c, flow: float) -> VioFrame:
        """A resting camera's frame: its pose from :meth:`_still_pose`, with a covariance relative
        to keyframe ``newest`` from the image motion allowed (rotation) and
        ``still_translation_sigma_m``; the window is not updated."""
        s = self.settings
        rot_sigma = s.init.still_flow_px / max(camera.fx, camera.fy)
        C = np.diag([rot_sigma ** 2] * 3 + [s.still_translation_sigma_m ** 2] * 3)
        self.history.add_frame(frame_id, self.session, newest, T_w_c, C)
        self._last_visual_t = t  # the images confirm the rest
        st = self._newest_state()
        return VioFrame(frame_id, VioStatus.STILL, f"at rest: IMU still, keypoints moved {flow:.2f} px since the "
                                                   f"previous frame (rotation removed); position of keyframe {newest}",
                        self.history.pose(frame_id), C, False, 0, st.velocity_w, st.accel_bias, st.gyro_bias)

    def _track(self, frame_id: int, t: float, camera: Camera, features: Features) -> VioFrame:
        s = self.settings
        w = self.landmarks.window
        newest = w.keyframe_ids[-1]
        rest = self._still_pose(t, camera, features, newest)
        if rest is not None:
            return self._trusted(self._still_frame(frame_id, t, camera, newest, *rest))
        state = self._newest_state()
        pred, pred_cov, reason = self.factors.predict(state, t)
        if pred is None:
            return self._lose(frame_id, reason)
        T_i_c = invert_transform(self.factors.T_c_i)
        T_prior = pred.T_w_i @ T_i_c
        # the prediction's uncertainty: preintegration noise, and the newest keyframe's velocity
        # and biases (not in the window's pose marginals) through the elapsed time
        dt = t - state.t
        C_prior = pred_cov + np.diag([(s.predict_gyro_sigma * dt) ** 2] * 3
                                     + [(s.predict_velocity_sigma * dt) ** 2] * 3)
        try:
            fl = self.landmarks.process(frame_id, t, camera, T_prior, features, prior_covariance=C_prior)
        except (InputError, RuntimeError) as exc:
            return self._lose(frame_id, f"the window update failed: {exc}")
        self.last_update = fl.update
        if fl.keyframe:
            why = self._health()
            if why:
                return self._lose(frame_id, why)
            # the frames since the previous keyframe are re-posed between the two (a bridge)
            self._bridged += [(f, ft, a, frame_id) for f, ft, a in self._unbridged]
            self._unbridged = []
            self._sync_history()
            T, C, anchor = w.pose(frame_id), np.zeros((6, 6)), frame_id
            n_lm = len(fl.points)  # landmarks observed in this keyframe
            visual = n_lm >= s.min_tracked_landmarks
        else:
            visual = fl.points.pose_refined and fl.points.associated >= s.min_tracked_landmarks
            anchor = newest
            if visual:
                T, C = fl.points.T_w_c, fl.points.covariance
            else:
                T, C = T_prior, C_prior
            n_lm = int(fl.points.associated)
            self.history.add_frame(frame_id, self.session, anchor, T, C)
            self._unbridged.append((frame_id, t, anchor))
        if visual:
            self._last_visual_t = t
        elif t - self._last_visual_t > s.max_imu_only_s:
            return self._lose(frame_id, f"no visual support for {t - self._last_visual_t:.1f} s "
                                        f"(> {s.max_imu_only_s} s)")
        self.landmark_log.record(frame_id, fl, len(w.keyframe_ids), self._scale_sigma())
        st = self._newest_state()
        status = VioStatus.TRACKING if visual else VioStatus.IMU_ONLY
        why = "" if visual else f"pose from the IMU alone ({n_lm} landmarks < {s.min_tracked_landmarks})"
        out = VioFrame(frame_id, status, why, self.history.pose(frame_id), C, fl.keyframe, n_lm, st.velocity_w,
                       st.accel_bias, st.gyro_bias)
        return self._trusted(out)

    def _trusted(self, out: VioFrame) -> VioFrame:
        """``out``, or without its pose (status converging) while the scale is not known well enough."""
        s = self.settings
        sigma, distance = self.history.window_span_sigma()
        if sigma <= max(s.max_scale_sigma * distance, s.min_span_sigma_m):
            return out
        return replace(out, status=VioStatus.CONVERGING, T_w_c=None, covariance=None,
                       reason=f"converging: the metric scale is known to {sigma / max(distance, 1e-12):.1%} "
                              f"(> {s.max_scale_sigma:.0%}); the pose is kept for later")



