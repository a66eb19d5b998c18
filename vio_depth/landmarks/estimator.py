"""Per-frame driver of the landmark window: matching, keyframe choice, query.

One :meth:`LandmarkEstimator.process` call per frame, in order, with the frame's
features (extracted once by the caller, as the pipeline does):

1. the frame is matched with the newest ``match_keyframes`` keyframes of the window
   (their features are kept while they are in the window); a matcher that can use a known
   relative pose (:class:`matchers.PoseGuidedMatcher`, e.g. SIFT with ``[matcher.guided]``
   on) gets each keyframe's pose relative to the frame's prior, with their covariance
   (:meth:`LandmarkEstimator.epipolar_priors`), as the two-view path gives its pairs';
2. its landmark points are queried (:meth:`LandmarkWindow.query`);
3. it becomes a keyframe when the two-view geometry with the newest keyframe predicts a
   median relative depth sigma below ``keyframe_relative_sigma`` (enough new parallax,
   measured against pixel and pose uncertainty: no scene-scale threshold), when fewer
   than ``keyframe_min_tracked_fraction`` of the newest keyframe's landmarks are found
   again, or after ``max_keyframe_gap`` frames; a keyframe is inserted, the window
   refined, and the frame's points re-read from the refined window.

With a :class:`~.backend.ProcessWindow` (:class:`~.settings.WindowBackendSettings` kind
``process``) step 3 runs in a worker process instead (with ``start_inline``, except for the
window's second keyframe, which starts its landmarks -- the frames of a lag would have none --
and is inserted as inline, waiting for the worker): the frame is answered at once from
the window as it was (its points from step 2) and the keyframe is *submitted*; the next
frames are matched and queried against that window too, and the refined window is taken
over ``lag_frames`` frames later (:meth:`LandmarkEstimator.land`: the caller may take it
before a frame's own processing, e.g. to predict from it). With ``provisional_landmarks``
the frames meanwhile are matched and queried against a *provisional* window instead: the
last one taken over, extended by the pending keyframe, whose tracks are triangulated at its
estimated pose (:meth:`WindowSnapshot.with_keyframe <.snapshot.WindowSnapshot.with_keyframe>`),
so that they see the landmarks it started, as they would inline (the keyframe's own frame
keeps the points of step 2). Meanwhile no new keyframe is chosen -- or, with
``max_pending_keyframes`` > 1, the frames are also matched with the pending keyframes and
step 3 tests them against the newest pending one (its pose as estimated when it was
submitted): a keyframe chosen then is queued in the worker behind it. :attr:`window` is
always the window last taken over (the refined one).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from matchers import EpipolarPrior, PoseGuidedMatcher
from triangulation import two_view_relative_sigma
from vio_core.camera import Camera
from vio_core.checks import check_transform
from vio_core.errors import InputError
from vio_core.geometry import adjoint, invert_transform

from .backend import ProcessWindow
from .motion import MotionFactorSource
from .query import frame_prior
from .settings import LandmarkSettings, WindowBackendSettings
from .snapshot import WindowSnapshot
from .tracks import FrameMatches
from .types import KeyframeInput, LandmarkPoints, WindowUpdate
from .window import LandmarkWindow

#: the keyframe parallax test takes its median relative depth sigma over at most this many
#: of the frame's matches with the newest keyframe (evenly spaced in the matcher's order): a
#: median of a few hundred decides as well as one of thousands, at a fraction of the
#: triangulation (a constant, not a setting: the settings are written into every output)
PARALLAX_MAX_MATCHES = 300


@dataclass(frozen=True)
class _Submitted:
    """Keyframes sent to the worker whose update was not taken over yet."""

    at: int  # frames processed at submission
    keyframes: tuple  # ((frame id, features, camera, keypoints), ...) in order
    lag: int  # frames after ``at`` at which the update is due
    timestamp: float  # seconds, of the last keyframe
    T_w_c: np.ndarray | None = None  # (4, 4) the last keyframe's pose estimate at submission
    tracked: int = 0  # landmarks of the window associated with it at submission
    # with ``provisional_landmarks``: (the keyframe as sent, its pose prior (4, 4) in the window,
    # that prior's covariance (6, 6) relative to the window's reference), for the provisional window
    provisional: tuple[KeyframeInput, np.ndarray, np.ndarray] | None = None


@dataclass(frozen=True)
class FrameLandmarks:
    """Result of :meth:`LandmarkEstimator.process` for one frame.

    Attributes:
        points: :class:`LandmarkPoints` for the rescaler.
        keyframe: whether the frame became a keyframe.
        keyframe_reason: why it did (or "").
        matches: matches with the window's keyframes (summed).
        pair_relative_sigma: median predicted relative depth sigma of its two-view
            matches with the newest keyframe (inf when undefined).
        update: the window update when it became a keyframe -- or when the window refused it
            (``update.ok`` False, with the reason: the window is unchanged and the frame is
            not a keyframe).
        frame_matches: the frame's matches with the window's newest keyframes (newest first).
        submitted: the frame was chosen as a keyframe and sent to the worker process
            (``keyframe`` is False: its update comes later, :meth:`LandmarkEstimator.land`;
            ``keyframe_reason`` says why it was chosen).
        landed: a submitted keyframe's update taken over at the start of this frame (when
            the caller did not take it itself), else None.
    """

    points: LandmarkPoints
    keyframe: bool
    keyframe_reason: str
    matches: int
    pair_relative_sigma: float
    update: WindowUpdate | None = None
    frame_matches: tuple[FrameMatches, ...] = ()
    submitted: bool = False
    landed: WindowUpdate | None = None


class LandmarkEstimator:
    """Landmark window + matcher + keyframe policy (see the module docstring).

    Args:
        settings: :class:`LandmarkSettings`.
        matcher: a ``matchers`` matcher (``match(features_a, features_b) -> Matches``).
        motion_factors: the window's :class:`~.motion.MotionFactorSource` (e.g. the odometry's
            IMU factors), or None: pose priors from the frames' poses.
        backend: a :class:`~.backend.ProcessWindow` to keep the window in (module
            docstring), or None: in this process.
        backend_settings: when its update is taken over (``lag_frames``, ``apply_when_ready``).
        motion_factory: with ``backend``: picklable callable building the worker's motion
            source (None: pose priors).
        motion_samples: with ``backend``: ``(t0, t1) -> samples`` for the worker's motion
            source between two keyframe times (seconds), or None.
        start_inline: with ``backend``: the window's second keyframe is inserted as inline (its
            frame waits for the worker) instead of submitted, so that the frames after it have
            landmarks at once (a points stage: KITTI-tiny's 7 frames lost 2 to a lag of 2
            without it). The odometry's window starts from its initialisation's keyframes
            instead, and a static start's single keyframe is extended in the worker.
    """

    def __init__(self, settings: LandmarkSettings, matcher, motion_factors: MotionFactorSource | None = None,
                 backend: ProcessWindow | None = None,
                 backend_settings: WindowBackendSettings = WindowBackendSettings(),
                 motion_factory: Callable[[], MotionFactorSource] | None = None,
                 motion_samples: Callable[[float, float], Any] | None = None, start_inline: bool = False):
        self.settings = settings
        self.matcher = matcher
        self.start_inline = start_inline
        self._args = (motion_factors, backend, backend_settings, motion_factory, motion_samples, start_inline)
        self._remote = backend
        self.backend_settings = backend_settings
        self._motion_samples = motion_samples
        self._provides_poses = motion_factors is not None and motion_factors.provides_poses
        if backend is None:
            self.window = LandmarkWindow(settings, motion_factors)
        else:
            #: in a worker process, the window as last taken over (a WindowSnapshot)
            backend.reset(settings, motion_factory)
            self.window = WindowSnapshot.empty(settings)
        #: the window extended by the pending keyframes (``provisional_landmarks``), or None
        self._provisional: WindowSnapshot | None = None
        self._features: dict[int, object] = {}
        self._last_tracked: int | None = None
        self._frames = 0  # frames processed (the lag of a submitted keyframe counts them)
        self._frame_id: int | None = None
        # keyframes submitted to the worker, oldest first (their updates are taken over in order)
        self._pending: list[_Submitted] = []
        #: every update of the keyframes taken over by the last :meth:`land` (more than one after
        #: :meth:`submit_keyframes`)
        self.landed_updates: tuple[WindowUpdate, ...] = ()

    def reset(self) -> None:
        """Forget everything (a new window)."""
        self.__init__(self.settings, self.matcher, *self._args)

    @property
    def in_worker(self) -> bool:
        """Whether the window lives in a worker process (a ``backend`` was given)."""
        return self._remote is not None

    @property
    def pending(self) -> int | None:
        """The frame id of a submitted keyframe whose update was not taken over yet (the
        newest of a batch), or None."""
        return self._pending[-1].keyframes[-1][0] if self._pending else None

    def land(self, frame_id: int, wait: bool = False) -> WindowUpdate | None:
        """Take a submitted keyframe's update over when it is due at frame ``frame_id``.

        Due: ``lag_frames`` frames after the keyframe (waiting for the worker if needed), or
        as soon as it is ready with ``apply_when_ready``, or now with ``wait``; the keyframes
        of :meth:`submit_keyframes` the same way after ``start_lag_frames``. The refined
        window replaces the current one; its keyframe's features are kept for matching.
        Queued keyframes are taken over in order, at most one per frame (every pending one
        with ``wait``). Call it (or let :meth:`process` call it) once per frame, before the
        frame's own processing; a second call for the same ``frame_id`` returns None (without
        ``wait``).

        Returns:
            The :class:`~.types.WindowUpdate` taken over (``ok`` False: the window refused the
            keyframe and is unchanged; with ``wait``: the last one), or None (nothing due;
            always None without a worker).

        Raises:
            NumericalError: the update failed in the worker; the window is unusable.
        """
        if frame_id != self._frame_id:
            self._frame_id = frame_id
            self._frames += 1
        elif not wait:  # decided at this frame's first call: an update ready only since is the next
            return None  # frame's (a caller that takes it over before process() would miss it)
        if not self._pending:
            return None
        first = self._pending[0]
        b = self.backend_settings
        due = self._frames - first.at >= first.lag or (b.apply_when_ready and self._remote.ready())
        if not (wait or due):
            return None
        landed: list[WindowUpdate] = []
        while self._pending and (wait or not landed):
            landed += self._take()
        self.landed_updates = tuple(landed)
        self._provisional = None
        for sub in self._pending:  # the keyframes still queued, on the window taken over
            self._extend(sub)
        return landed[-1]

    @property
    def _view(self) -> WindowSnapshot | LandmarkWindow:
        """What frames are matched and queried against: the provisional window, or the window."""
        return self.window if self._provisional is None else self._provisional

    def _extend(self, sub: _Submitted) -> None:
        """Extend the provisional window by a submitted keyframe (``provisional_landmarks``)."""
        if sub.provisional is not None:
            self._provisional = self._view.with_keyframe(*sub.provisional)

    def _keyframe_features_any(self, frame_id: int):
        """The features of a keyframe of the window or of a pending one."""
        if frame_id in self._features:
            return self._features[frame_id]
        return next(k[1] for sub in self._pending for k in sub.keyframes if k[0] == frame_id)

    def _take(self) -> tuple[WindowUpdate, ...]:
        """Take the oldest pending submission's updates and window over (waiting for them)."""
        keyframes = self._pending.pop(0).keyframes
        updates, snapshot = self._remote.batch_result()
        if snapshot is not None:
            self.window = snapshot
            inserted = keyframes[: len(updates) - (not updates[-1].ok)]
            for kf_id, features, _, _ in inserted:
                self._keep_features(kf_id, features)
            kf_id, _, camera, kp = inserted[-1]
            self._last_tracked = len(snapshot.query(camera, None, kp, frame_id=kf_id))
        return updates

    def _keep_features(self, frame_id: int, features) -> None:
        """Keep a keyframe's features for matching while it is in the window."""
        self._features[int(frame_id)] = features
        ids = self.window.keyframe_ids
        for k in list(self._features):
            if k not in ids:
                del self._features[k]

    def _samples(self, frame_id: int, timestamp: float):
        """The motion source's samples for keyframe ``frame_id`` (worker only), from the
        keyframe the worker will have inserted last before it, or None."""
        ids = self.window.keyframe_ids
        if self._remote is None or self._motion_samples is None or not (ids or self._pending):
            return None
        t0 = self._pending[-1].timestamp if self._pending else self.window.keyframe(ids[-1]).timestamp
        return self._motion_samples(t0, float(timestamp))

    def _pair_relative_sigma(self, kf_camera: Camera, T_kf, kf_uv: np.ndarray, camera: Camera,
                             keypoints: np.ndarray, points: LandmarkPoints, m: FrameMatches) -> float:
        """Median predicted sigma_z/z of two-view matches ``m`` with the newest keyframe (its
        camera, pose ``T_kf`` (4, 4) camera-to-world and keypoints ``kf_uv`` (K, 2) pixels), at
        the frame's (refined) pose and its covariance relative to that keyframe."""
        if len(m) < 5 or points.T_w_c is None or points.covariance is None or T_kf is None:
            return float("inf")
        T_cur = points.T_w_c
        # the pair's rotation is measured by its own matches to about sigma_px / (f sqrt(n))
        # radians whatever the prior says; the translation keeps its (prior or refined) sigma
        C_cur = points.covariance.copy()
        rot_var = (self.settings.multiview.pixel_sigma_px / camera.fx) ** 2 / max(len(m), 1)
        C_cur[:3, :] = C_cur[:, :3] = 0.0  # drop rotation and its cross terms
        C_cur[:3, :3] = np.minimum(np.diag(np.diag(points.covariance[:3, :3])), rot_var * np.eye(3))
        # a median over an evenly spaced subset of the matches (PARALLAX_MAX_MATCHES), in closed form:
        # the N-view triangulation (Gauss-Newton, outlier rounds) took 6-9 ms a call, this 1 ms
        # (docs/benchmarks.md "The keyframe decision's two-view sigma in closed form")
        pick = np.unique(np.linspace(0, len(m) - 1, min(len(m), PARALLAX_MAX_MATCHES)).astype(np.int64))
        mv = self.settings.multiview
        rel = two_view_relative_sigma(kf_uv[m.idx_keyframe[pick]], keypoints[m.idx_frame[pick]], kf_camera, camera,
                                      T_kf, T_cur, C_cur, mv.pixel_sigma_px, mv.max_residual_sigmas)
        rel = rel[np.isfinite(rel)]
        return float(np.median(rel)) if len(rel) >= 5 else float("inf")

    @staticmethod
    def epipolar_priors(window, keyframes: Sequence[int], camera: Camera, T_w_c,
                        prior_covariance=None) -> list[EpipolarPrior]:
        """The frame's pose relative to each of ``keyframes`` of ``window``, for pose-guided matching.

        The frame's prior (:func:`~.query.frame_prior`: ``T_w_c`` (4, 4) camera-to-world,
        metres, corrected like the newest keyframe; ``prior_covariance`` (6, 6) or None as
        there) in each keyframe's camera. Its covariance: the frame's relative to the newest
        keyframe plus the keyframe's relative to it (the window's conditional covariance),
        carried into the frame's perturbation (right, rotation rad then translation m);
        their correlation is left out (a wider band, never a narrower one for it).
        """
        T0, cov_frame = frame_prior(window, T_w_c, (), prior_covariance)
        relative = window.relative_covariances()
        ids = window.keyframe_ids
        priors = []
        for k in keyframes:
            T_k_cur = invert_transform(window.pose(k)) @ T0
            A = adjoint(invert_transform(T_k_cur))  # the keyframe's right perturbation, as the frame's
            cov = cov_frame + A @ relative[ids.index(k)] @ A.T
            priors.append(EpipolarPrior(camera, window.keyframe(k).camera, T_k_cur, 0.5 * (cov + cov.T)))
        return priors

    def process(self, frame_id: int, timestamp: float, camera: Camera, T_w_c, features,
                prior_covariance=None) -> FrameLandmarks:
        """Process the next frame (see the module docstring).

        Args:
            frame_id: increasing frame id.
            timestamp: seconds.
            camera: the frame's camera.
            T_w_c: (4, 4) the frame's pose prior, camera-to-world, metres.
            features: its ``matchers.Features`` (keypoints in raw pixels).
            prior_covariance: (6, 6) covariance of ``T_w_c`` relative to the newest keyframe
                (e.g. from IMU preintegration), or None (the settings' relative pose prior).
        """
        s = self.settings
        T_w_c = check_transform("T_w_c", T_w_c)
        landed = self.land(frame_id)
        kp = np.asarray(features.keypoints, np.float64)
        w = self._view
        if not w.keyframe_ids:
            update = self.insert_keyframe(frame_id, timestamp, camera, T_w_c, features, ())
            if not update.ok:
                return FrameLandmarks(LandmarkPoints.empty(update.reason, T_w_c), False, "", 0, float("inf"), update,
                                      landed=landed)
            return FrameLandmarks(LandmarkPoints.empty("first keyframe: no landmarks yet", T_w_c), True,
                                  "first frame", 0, float("inf"), update, landed=landed)
        newest_first = w.keyframe_ids[::-1][: s.match_keyframes]
        if isinstance(self.matcher, PoseGuidedMatcher):
            priors = self.epipolar_priors(w, newest_first, camera, T_w_c, prior_covariance)
            matches = [FrameMatches.from_matches(k, self.matcher.match_with_pose(features, self._keyframe_features_any(k),
                                                                                 prior))
                       for k, prior in zip(newest_first, priors)]
        else:
            matches = [FrameMatches.from_matches(k, self.matcher.match(features, self._keyframe_features_any(k)))
                       for k in newest_first]
        points = w.query(camera, T_w_c, kp, matches, prior_covariance=prior_covariance)
        if len(self._pending) >= self.backend_settings.max_pending_keyframes:
            # the worker is refining the window and its queue is full: no new keyframe meanwhile
            return FrameLandmarks(points, False, "", sum(len(m) for m in matches), float("inf"),
                                  frame_matches=tuple(matches), landed=landed)
        if self._pending and self._provisional is None:  # the newest keyframe is queued in the worker:
            # matched and tested as it was sent
            queued = [k for sub in self._pending for k in sub.keyframes][::-1][: s.match_keyframes]
            matches = [FrameMatches.from_matches(k[0], self.matcher.match(features, k[1])) for k in queued] + matches
            newest, _, kf_camera, kf_uv = queued[0]
            T_kf, last_tracked = self._pending[-1].T_w_c, self._pending[-1].tracked
        else:
            newest, kf_camera = newest_first[0], w.keyframe(newest_first[0]).camera
            T_kf, kf_uv, last_tracked = w.pose(newest), w.tracks.keypoints(newest), self._last_tracked
        n_matches = sum(len(m) for m in matches)
        rel = self._pair_relative_sigma(kf_camera, T_kf, kf_uv, camera, kp, points, matches[0])
        reason = ""
        if frame_id - newest >= s.max_keyframe_gap:
            reason = f"{frame_id - newest} frames since the newest keyframe"
        elif rel <= s.keyframe_relative_sigma:
            reason = f"parallax: two-view relative depth sigma {rel:.3f} <= {s.keyframe_relative_sigma}"
        elif last_tracked and points.associated < s.keyframe_min_tracked_fraction * last_tracked:
            reason = f"{points.associated} of the newest keyframe's {last_tracked} landmarks found"
        if not reason:
            return FrameLandmarks(points, False, "", n_matches, rel, frame_matches=tuple(matches), landed=landed)
        if self._remote is not None and not (self.start_inline and len(w.keyframe_ids) < 2):
            sent = tuple(matches[: s.match_keyframes])  # the newest keyframes, queued ones first (as inline)
            kf = self._keyframe_input(frame_id, timestamp, camera, T_w_c, kp, sent)
            self._remote.submit(kf, None, self._samples(frame_id, timestamp))
            provisional = None
            if self.backend_settings.provisional_landmarks:
                # the provisional keyframe sits at its prior, not at the pose the landmarks refined:
                # that pose's error is correlated with theirs (e.g. their common scale), which its
                # covariance leaves out, and the tracks triangulated from it would inherit it with
                # too small a sigma
                provisional = (kf, *frame_prior(w, T_w_c, matches, prior_covariance))
            sub = _Submitted(self._frames, ((int(frame_id), features, camera, kp),), self.backend_settings.lag_frames,
                             float(timestamp), points.T_w_c, int(points.associated), provisional)
            self._pending.append(sub)
            self._extend(sub)
            if self._provisional is not None and frame_id in self._provisional.keyframe_ids:
                # its landmarks in the provisional window: what the next frames' tracked fraction is
                # measured against (the frame itself keeps its refined pose and the points of step 2)
                self._last_tracked = len(self._provisional.query(camera, None, kp, frame_id=frame_id))
            return FrameLandmarks(points, False, reason, n_matches, rel, None, tuple(matches), submitted=True,
                                  landed=landed)
        # inline -- or, in a worker with start_inline, the window's second keyframe, which starts its
        # landmarks: the frames of a lag would have none at all, so this frame waits for it
        update = self.insert_keyframe(frame_id, timestamp, camera, T_w_c, features, tuple(matches))
        if not update.ok:
            return FrameLandmarks(points, False, "", n_matches, rel, update, tuple(matches), landed=landed)
        points = self._view.query(camera, None, kp, frame_id=frame_id)
        self._last_tracked = len(points)
        return FrameLandmarks(points, True, reason, n_matches, rel, update, tuple(matches), landed=landed)

    def keyframe_features(self, frame_id: int):
        """The ``matchers.Features`` of a keyframe in the window (None for any other frame)."""
        return self._features.get(int(frame_id))

    def insert_keyframe(self, frame_id, timestamp, camera, T_w_c, features, matches,
                        initial: Any | None = None) -> WindowUpdate:
        """Insert a keyframe directly (e.g. the keyframes of a VIO initialisation), bypassing the policy.

        ``matches``: :class:`FrameMatches` with keyframes of the window; ``T_w_c`` its pose
        prior (or None when the motion factor source gives it); ``features`` are kept for
        matching later frames (not when the window refused the keyframe: ``update.ok``
        False); ``initial``: the motion factor source's own initial state for it
        (:meth:`LandmarkWindow.add_keyframe`).
        """
        kf = self._keyframe_input(frame_id, timestamp, camera, T_w_c, np.asarray(features.keypoints, np.float64),
                                  matches)
        if self._remote is None:
            update = self.window.add_keyframe(kf, initial)
        else:
            if self._pending:
                self.land(self._frame_id, wait=True)
            update, snapshot = self._remote.insert(kf, initial, self._samples(frame_id, timestamp))
            if snapshot is not None:
                self.window = snapshot
                self._provisional = None
        if not update.ok:
            return update
        self._keep_features(frame_id, features)
        return update

    def submit_keyframes(self, keyframes: Sequence[tuple], lag: int | None = None) -> None:
        """Send the first keyframes of an empty window to the worker in one batch (e.g. a VIO
        initialisation's), bypassing the policy; returns at once. :meth:`land` takes them over
        ``start_lag_frames`` frames later (:attr:`landed_updates`: one update each, up to the
        first refused one).

        Args:
            keyframes: ``(frame_id, timestamp, camera, T_w_c, features, matches, initial)``
                each, in order (:meth:`insert_keyframe`'s arguments); ``matches`` with
                keyframes of the window once the earlier ones are in.
            lag: frames until they are due (default ``start_lag_frames``).
        """
        if self._remote is None:
            raise InputError("landmarks: submit_keyframes needs the window in a worker process")
        if self.window.keyframe_ids or self._pending:
            raise InputError("landmarks: submit_keyframes starts an empty window")
        batch, kept, before = [], [], None
        for frame_id, timestamp, camera, T_w_c, features, matches, initial in keyframes:
            kp = np.asarray(features.keypoints, np.float64)
            samples = None if before is None or self._motion_samples is None else \
                self._motion_samples(before, float(timestamp))
            batch.append((self._keyframe_input(frame_id, timestamp, camera, T_w_c, kp, tuple(matches)), initial,
                          samples))
            kept.append((int(frame_id), features, camera, kp))
            before = float(timestamp)
        self._remote.submit_batch(batch)
        self._pending.append(_Submitted(self._frames, tuple(kept),
                                        self.backend_settings.start_lag_frames if lag is None else int(lag), before))

    def _keyframe_input(self, frame_id, timestamp, camera, T_w_c, keypoints, matches) -> KeyframeInput:
        if self._provides_poses:
            # the motion factor source gives every keyframe's pose, and the frames' pose priors are
            # its predictions in the window's current frame (VIO): they are not sequence poses that
            # the window corrects the way it corrected their keyframe's
            T_w_c = None
        return KeyframeInput(int(frame_id), float(timestamp), camera, T_w_c, keypoints, matches)
