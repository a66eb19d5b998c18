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
* ``still``: tracking, and the zero-velocity test (:mod:`vio_depth.vio.rest`: IMU chi-square
  and image disparity, as OpenVINS) says the camera rests: the frame keeps the position of
  the frame before the rest, with a covariance that grows with the time at rest; the window
  is not updated, so a resting camera neither drifts on the IMU alone nor loses tracking for
  lack of parallax;
* ``imu_only``: tracking, but the frame's pose could not be refined against landmarks
  (too few): the IMU prediction is used, trusted for at most ``max_imu_only_s``;
* ``lost``: the estimate diverged (speed, biases beyond plausible bounds) or had no visual
  support for longer than ``max_imu_only_s``: the frame has **no pose**, the window is
  dropped and the initialisation starts again (a new session: poses of different
  sessions are never related).

Poses kept (:attr:`VioEstimator.history`): keyframes follow the window's latest estimate
until they are marginalised; the frames between them are posed when processed and again by
the IMU after every window update (:mod:`vio_depth.vio.bridge`).

Where the window's keyframe updates run (``settings.backend``,
:class:`~vio_depth.landmarks.WindowBackendSettings`): ``inline`` (the default), a keyframe's
frame waits for its update; ``process``, the update runs in a worker process
(:mod:`vio_depth.landmarks.backend`) while the next frames are posed by IMU prediction and a
motion-only refinement against the window as it was; it is taken over ``lag_frames`` frames
later, before that frame's prediction (health check, bridges and history as for an inline
keyframe). The keyframe's own frame keeps the pose it was given when processed (anchored to
the previous keyframe) until the window's refined pose replaces it. An initialisation's
window is built there too, taken over ``start_lag_frames`` later (the frames between wait);
after an offline sequence's last frame :meth:`VioEstimator.finish` takes over what is pending.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import replace

import numpy as np

from matchers import Features, Matcher
from vio_core.camera import Camera
from vio_core.errors import InputError, NumericalError
from vio_core.geometry import invert_transform

from ..frame import ImuData
from ..landmarks import FrameMatches, LandmarkEstimator, ProcessWindow, WindowUpdate
from .bridge import FrameBridges
from .history import PoseHistory
from .imu_factors import ImuFactors, KeyframeState
from .initializer import Candidate, Initializer, InitKind, InitResult
from .landmark_feed import KEPT_FRAMES, LandmarkLog, OdometryLandmarks, relative_scale_sigma
from .matching import EpipolarGatedMatcher
from .init_remote import RemoteInitializer, catch_up_candidates
from .rest import RestDetector, RestTest
from .settings import VioSettings
from .status import VioFrame, VioStatus, implausible

log = logging.getLogger(__name__)


class VioEstimator:
    """Visual-inertial odometry over the frames of one camera (module docstring).

    Args:
        imu: the IMU samples (with ``T_c_i``, noise densities, gravity).
        matcher: matches the frames' features (the same matcher extracted them).
        settings: :class:`~vio_depth.vio.VioSettings`.
        backend: with ``settings.backend.kind`` "process": the window's worker, started
            earlier by the caller (its interpreter takes 1-3 s to start); default: one started
            here. Ignored for "inline".
    """

    def __init__(self, imu: ImuData, matcher: Matcher, settings: VioSettings = VioSettings(),
                 backend: ProcessWindow | None = None):
        if imu is None:
            raise InputError("vio: no IMU samples")
        self.settings = settings
        self.matcher = matcher
        self._gate = EpipolarGatedMatcher(matcher, settings.epipolar_threshold_px)
        self.factors = ImuFactors(imu, settings)
        self.initializer = Initializer(imu, self._gate, settings, self.factors.params)
        self.history = PoseHistory(settings.history_frames)
        self.landmarks: LandmarkEstimator | None = None
        #: an initialisation whose window the worker is building (``settings.backend.kind`` "process")
        self._starting: InitResult | None = None
        #: candidates collected while the start's attempt ran in the worker, inserted after its keyframes
        self._catch_up: list[Candidate] = []
        self.session = 0
        self._times: dict[int, float] = {}
        self._last_visual_t = -np.inf
        self._last_id: int | None = None
        self.rest = RestDetector(self.factors, matcher, settings.rest, settings.imu.max_sample_gap_s)
        #: the landmark window's last update and the last initialisation (diagnostics)
        self.last_update = None
        self.last_init: InitResult | None = None
        self.bridges = FrameBridges(self.factors, settings.bridge_every_update)
        #: the landmarks each tracked frame saw (``--points vio`` reads them: :meth:`frame_landmarks`)
        self.landmark_log = LandmarkLog(min(settings.history_frames, KEPT_FRAMES))
        #: the worker process of the landmark window (``settings.backend.kind`` "process"), or None
        self.backend = None
        #: offers the frames to the initializer: itself, or with the dynamic attempt in the worker
        self._init: Initializer | RemoteInitializer = self.initializer
        self._remote_init: RemoteInitializer | None = None
        if settings.backend.kind == "process":
            self.backend = ProcessWindow() if backend is None else backend
            self._init = self._remote_init = RemoteInitializer(self.initializer, self.backend, settings.backend)

    @property
    def imu(self) -> ImuData:
        return self.factors.imu

    def update_samples(self, imu: ImuData) -> None:
        """Use ``imu`` (the samples so far plus newer ones; streaming input) from now on.
        Samples before :meth:`samples_needed_since` may be left out."""
        self.factors.update_samples(imu)
        self.initializer.update_samples(imu)

    def samples_needed_since(self) -> float | None:
        """Seconds before which the odometry reads no IMU sample again, or None before the first
        frame: the oldest of the window's keyframes (its factors, bridges and predictions start
        there), the rest anchor, the initialisation's candidates and the lookbacks of the
        static start and the rest test from the newest frame. A stream forgets older samples
        (:class:`~vio_depth.pipeline.feed.StreamInputs`); without that they grow by the IMU
        rate for as long as it runs."""
        if self._last_id is None:
            return None
        s = self.settings
        t = self._times[self._last_id]
        times = [t - max(s.init.lookback_s, s.rest.gyro_bias_window_s, s.rest.min_imu_s)]
        if self.tracking:
            times += [self._times[f] for f in self.landmarks.window.keyframe_ids if f in self._times]
        else:
            times += self._init.candidate_times()
        if self.rest.anchor is not None:
            times.append(self.rest.anchor.t)
        return min(times)

    @property
    def tracking(self) -> bool:
        """The odometry has a window and tracks (not initialising, nor waiting for its worker's start)."""
        return self.landmarks is not None and self._starting is None

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

    def _sync_history(self, defer: bool = False) -> None:
        w = self.landmarks.window
        ids = w.keyframe_ids
        self.history.update_keyframes(self.session, ids, np.stack([w.pose(f) for f in ids]), w.joint_covariance(ids))
        self.bridges.refresh(w, self._times, self.history, self.session, defer)

    def _health(self) -> str:
        """Why the newest keyframe's state is implausible ("" when it is fine)."""
        try:
            return implausible(self._newest_state(), self.settings)
        except NumericalError as error:  # an expected outcome here: the odometry is lost, not the run
            return str(error)

    def _lose(self, frame_id: int, reason: str) -> VioFrame:
        log.info("vio: lost at frame %d: %s", frame_id, reason)
        self.landmarks = None
        self._starting = None
        self._init.reset()
        self.rest.reset()
        self.session += 1
        return VioFrame(frame_id, VioStatus.LOST, f"odometry lost: {reason}; re-initialising")

    # ------------------------------------------------------------------ start
    def _start_keyframes(self, res: InitResult) -> list[tuple]:
        """The initialisation's keyframes as :meth:`LandmarkEstimator.insert_keyframe`'s
        arguments, in order (a new window and session are started)."""
        s = self.settings
        self.session += 1
        if self.backend is None:
            self.landmarks = LandmarkEstimator(s.window, self._gate, self.factors)
        else:
            self.landmarks = LandmarkEstimator(s.window, self._gate, self.factors, self.backend, s.backend,
                                               functools.partial(ImuFactors, self.imu, s),
                                               self.factors.samples_between)
        T_i_c = invert_transform(self.factors.T_c_i)
        out, before = [], set()
        for k, st in zip(res.keyframes, res.states):
            self._times[k.frame_id] = k.t
            matches = tuple(m for m in k.matches if m.keyframe in before)
            # the initialisation's state: the first keyframe's prior, the others' initial values
            out.append((k.frame_id, k.t, k.camera, st.T_w_i @ T_i_c, k.features, matches, st))
            before.add(k.frame_id)
        self._catch_up = catch_up_candidates(self.initializer.candidates(), res, s.backend.catch_up_keyframes)
        for c in self._catch_up:  # posed by the IMU from the keyframe before (no initial state)
            self._times[c.frame_id] = c.t
            matches = tuple(FrameMatches.from_matches(a[0], self._gate.match(c.features, a[4]))
                            for a in out[::-1][: s.window.match_keyframes])
            out.append((c.frame_id, c.t, c.camera, None, c.features, matches, None))
        return out

    def _start(self, res: InitResult) -> str:
        """Build the window from an initialisation here; "" on success, else why it was refused."""
        try:
            for args in self._start_keyframes(res):
                upd = self.landmarks.insert_keyframe(*args[:6], initial=args[6])
                if not upd.ok:
                    self.landmarks = None
                    return f"the window could not start: {upd.reason}"
                log.debug("vio: start %s", upd.summary())
        except NumericalError as exc:
            self.landmarks = None
            return f"the window could not start: {exc}"
        return self._started(res)

    def _submit_start(self, res: InitResult) -> None:
        """Send the initialisation's keyframes to the window worker; :meth:`_land_start` takes
        the window over ``start_lag_frames`` frames after the initialisation (its attempt's
        submission), at least one frame later, and the frames meanwhile wait (initialising)."""
        keyframes = self._start_keyframes(res)  # builds self.landmarks
        since = 0 if self._remote_init is None else self._remote_init.landed_after  # the attempt's
        self.landmarks.submit_keyframes(keyframes, max(self.settings.backend.start_lag_frames - since, 1))
        self._starting = res

    def _land_start(self, frame_id: int, final: bool = False) -> tuple[bool, str]:
        """``(landed, why)``: whether the window worker's start is taken over at this frame
        (``final``: now, waiting for it, after the sequence's last frame), and why it was
        refused ("" when the odometry started)."""
        try:
            update = self.landmarks.land(frame_id, wait=final)
        except NumericalError as exc:
            update, why = None, f"the window could not start: {exc}"
        else:
            if update is None:
                return False, ""
            why = "" if update.ok else f"the window could not start: {update.reason}"
        res, self._starting = self._starting, None
        if not why:
            why = self._started(res, final)
        if why:
            self.landmarks = None
        return True, why

    def _started(self, res: InitResult, final: bool = False) -> str:
        """Check the window built from an initialisation and start tracking from it; "" on
        success, else why it was refused (the caller drops the window). ``final``: taken over
        after the sequence's last frame (which waited too)."""
        s = self.settings
        why = self._health()
        if not why and res.kind == InitKind.DYNAMIC and len(res.keyframes) > 1:
            w = self.landmarks.window
            T_i_c = invert_transform(self.factors.T_c_i)
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
        # the other frames of the initialisation, and those that waited for its window built in the
        # worker: posed between the keyframes around them, again after window updates
        keyframes = list(res.keyframes) + self._catch_up
        ids = {k.frame_id for k in keyframes}
        waited = {f: ft for f, ft in self._times.items() if ft > keyframes[-1].t and (f < self._last_id or final)}
        frames = sorted((dict(res.frames) | waited).items(), key=lambda ft: ft[1])
        self.bridges.start([(k.frame_id, k.t) for k in keyframes], [(f, t) for f, t in frames if f not in ids])
        self._sync_history()
        self._last_visual_t = keyframes[-1].t
        self.landmark_log.record_window_keyframes(
            self.landmarks, [(k.frame_id, k.camera, np.asarray(k.features.keypoints, np.float64)) for k in keyframes],
            self._scale_sigma(), f"{res.kind} initialisation keyframe")
        return ""

    def finish(self) -> None:
        """The sequence ended (an offline run, before its backward pass): take over, waiting for
        it, what the window's worker still has (an initialisation attempt in flight and its start's
        window, a keyframe update not due yet) as a later frame would have, so that the frames
        that waited get poses; those after the newest keyframe without one are posed by IMU
        prediction from it (within ``max_imu_only_s``). Inline, nothing is pending."""
        if self.backend is None or self._last_id is None:
            return
        last, why = self._last_id, ""
        if self.landmarks is None:  # initialising: an attempt in flight?
            res = self._remote_init.finish()
            if res is None or not res.ok:
                return
            self._submit_start(res)
        if self._starting is not None:
            res = self._starting
            why = self._land_start(last, final=True)[1]
            if not why:
                self._log_start(res, last)
        else:
            try:
                update = self.landmarks.land(last, wait=True)
                why = "" if update is None else self._landed(update)
            except NumericalError as exc:
                why = str(exc)
        if why:  # the poses so far stay as they are
            log.info("vio: what the worker had at the end was refused: %s", why)
            return
        self.bridges.settle()
        state = self._newest_state()
        for f, t, kf in self.bridges.following():
            if f not in self.history and t - state.t <= self.settings.max_imu_only_s:
                T, C, _ = self.factors.predict_camera(state, t)
                if T is not None:
                    self.history.add_frame(f, self.session, kf, T, C)

    # ------------------------------------------------------------------ per frame
    def process(self, frame_id: int, t: float, camera: Camera, features: Features) -> VioFrame:
        """Process the next frame (ids and times increasing)."""
        out = self._process(frame_id, t, camera, features)
        posed = out.T_w_c is not None or (out.status == VioStatus.CONVERGING and frame_id in self.history)
        self.rest.observe(frame_id, t, features, posed)
        return out

    def _process(self, frame_id: int, t: float, camera: Camera, features: Features) -> VioFrame:
        s = self.settings
        if self._last_id is not None and frame_id <= self._last_id:
            raise InputError(f"vio: frames must come in order, got {frame_id} after {self._last_id}")
        self._last_id = int(frame_id)
        self._times[int(frame_id)] = float(t)
        self._gate.camera = camera
        if len(self._times) > 4 * self.settings.history_frames:
            for k in sorted(self._times)[: len(self._times) // 2]:
                self._times.pop(k)
        if self._starting is not None:  # the initialisation's window is being built in the worker
            res = self._starting
            landed, why = self._land_start(frame_id)
            if not landed:
                return VioFrame(frame_id, VioStatus.INITIALISING, f"{res.kind.value} initialisation at frame "
                                f"{res.keyframes[-1].frame_id}: the window is being built in the worker process")
            if why:
                self.initializer.refuse(why, drop_oldest=False)
                return VioFrame(frame_id, VioStatus.INITIALISING, f"initialisation refused: {why}")
            return self._track_started(res, frame_id, t, camera, features)
        if not self.tracking:
            res = self._init.process(frame_id, t, camera, features)
            if not res.ok:
                return VioFrame(frame_id, VioStatus.INITIALISING, res.reason)
            if self.backend is not None and s.backend.start_lag_frames > 0:
                self._submit_start(res)
                return VioFrame(frame_id, VioStatus.INITIALISING, f"{res.kind.value} initialisation: the window is "
                                "being built in the worker process")
            why = self._start(res)
            if why:
                self.initializer.refuse(why, drop_oldest=False)
                return VioFrame(frame_id, VioStatus.INITIALISING, f"initialisation refused: {why}")
            if res.keyframes[-1].frame_id != frame_id:  # an attempt run in the worker, taken over here
                return self._track_started(res, frame_id, t, camera, features)
            self._log_start(res, frame_id)
            st = self._newest_state()
            return self._trusted(VioFrame(frame_id, VioStatus.TRACKING, f"{res.kind.value} initialisation",
                                          self.history.pose(frame_id), np.zeros((6, 6)), True, 0, st.velocity_w,
                                          st.accel_bias, st.gyro_bias, res.kind))
        return self._track(int(frame_id), float(t), camera, features)

    def _track_started(self, res: InitResult, frame_id: int, t: float, camera: Camera,
                       features: Features) -> VioFrame:
        """The first frame after a start whose newest keyframe is an earlier frame: tracked from
        that keyframe; the frames since it were not (a rest, a static start's, continues from it)."""
        self._log_start(res, frame_id)
        kf = res.keyframes[-1]
        self.rest.observe(kf.frame_id, kf.t, kf.features, True)
        return replace(self._track(int(frame_id), float(t), camera, features), initialised=res.kind)

    def _log_start(self, res: InitResult, frame_id: int) -> None:
        al = res.alignment
        log.info("vio: %s initialisation at frame %d (%d keyframes%s)", res.kind.value, frame_id,
                 len(res.keyframes),
                 "" if al is None else f"; scale {al.scale:.4g} +- {al.scale_sigma:.1%}, gravity error "
                                       f"{al.gravity_error:+.2f} m/s^2, excitation {al.excitation:.2f} m/s^2")
        for upd in self.landmarks.landed_updates:  # a start built in the worker (inline: logged by _start)
            log.debug("vio: start %s", upd.summary())
        self.last_init = res

    def _still_frame(self, frame_id: int, t: float, rest: RestTest) -> VioFrame:
        """A resting camera's frame (:mod:`vio_depth.vio.rest`); the window is not updated."""
        self.history.add_frame(frame_id, self.session, self.rest.anchor.keyframe, rest.T_w_c, rest.covariance)
        self._last_visual_t = t  # the images confirm the rest
        st = self._newest_state()
        return VioFrame(frame_id, VioStatus.STILL, rest.reason, self.history.pose(frame_id), rest.covariance, False, 0,
                        st.velocity_w, st.accel_bias, st.gyro_bias)

    def _landed(self, update: WindowUpdate) -> str:
        """Take over a keyframe refined in the worker process; "" or why the odometry is lost."""
        self.last_update = update
        if not update.ok:  # the IMU could not link the keyframe
            return f"the window update failed: {update.reason}"
        why = self._health()
        if why:
            return why
        kf = update.frame_id
        self.bridges.close(kf, self._times[kf])  # frames before it bridged; those after it now follow it
        self._sync_history(defer=self.settings.defer_bridge_refresh)  # (re-posed at the next frame then)
        return ""

    def _track(self, frame_id: int, t: float, camera: Camera, features: Features) -> VioFrame:
        s = self.settings
        try:  # a keyframe refined in the worker process, when due: predict from it
            landed = self.landmarks.land(frame_id)
        except NumericalError as exc:
            return self._lose(frame_id, f"the window update failed: {exc}")
        if landed is not None:
            why = self._landed(landed)
            if why:
                return self._lose(frame_id, why)
        else:
            self.bridges.settle()  # a refresh deferred from the previous take-over
        w = self.landmarks.window
        newest = w.keyframe_ids[-1]
        state = self._newest_state()
        rest = self.rest.test(t, camera, features, newest, state, self.history)
        if rest.rest:
            return self._trusted(self._still_frame(frame_id, t, rest))
        T_prior, C_prior, reason = self.factors.predict_camera(state, t)
        if T_prior is None:
            return self._lose(frame_id, reason)
        try:
            fl = self.landmarks.process(frame_id, t, camera, T_prior, features, prior_covariance=C_prior)
        except NumericalError as exc:
            return self._lose(frame_id, f"the window update failed: {exc}")
        if fl.update is not None and not fl.update.ok:  # the IMU could not link the keyframe
            return self._lose(frame_id, f"the window update failed: {fl.update.reason}")
        if fl.update is not None or landed is None:
            self.last_update = fl.update
        if fl.keyframe:
            why = self._health()
            if why:
                return self._lose(frame_id, why)
            self.bridges.close(frame_id)  # the frames since the previous keyframe: bridged between the two
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
            self.bridges.add(frame_id, t, anchor)
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



