"""Sliding-window refinement of keyframe poses and landmarks with gtsam.

The window holds the newest ``window_keyframes`` keyframes. Each new keyframe:

1. joins the :class:`~vio_depth.landmarks.tracks.TrackTable` through its matches;
2. enters the factor graph with the factors and initial values of its
   :class:`~.motion.MotionFactorSource` (:mod:`.motion`): by default
   (:class:`~.motion.PosePriorFactors`) its **pose priors** (:class:`PosePriorSettings`),
   an absolute ``PriorFactorPose3`` and a ``BetweenFactorPose3`` to the previous keyframe
   carrying the sequence's relative motion; with the odometry, IMU preintegration between
   the two keyframes. A source with no factors for it refuses the keyframe (a status with
   its reason; the window is unchanged);
3. every track with two or more observations is triangulated over the window
   (:func:`triangulation.multiview.triangulate_tracks`, with the poses' current
   uncertainty) -- again only where the new keyframe changed the track; an unchanged track
   keeps the last update's result (:mod:`.incremental`), and with
   ``settings.gate_extended_tracks`` a track the new keyframe only extended keeps its point,
   the new observation judged against it; its outlier observations are split
   off the track, and the VALID ones
   become ``Point3`` landmarks with ``GenericProjectionFactorCal3DS2`` factors (raw pixels,
   the camera's distortion; Huber kernel);
4. Levenberg-Marquardt refines poses and landmarks together (:mod:`.graph`); the scale is
   held by the priors (or the motion factors), never by the images. With
   ``settings.solver = "isam2"`` gtsam's iSAM2 takes only the keyframe's changes instead
   (:mod:`.isam`);
5. the keyframe poses' joint marginal covariance comes from ``gtsam.Marginals``
   (bookkeeping: :mod:`.covariance`), and each
   landmark's point, covariance and depth (with sigma) in every keyframe observing it
   from a final multi-view triangulation at the refined poses with those covariances (of
   the tracks seen by the newest ``refresh_keyframes`` keyframes and of the tracks that
   changed; the others keep their last result);
6. beyond ``window_keyframes`` the oldest keyframe is **marginalised** (:mod:`.marginalisation`):
   its projection factors are dropped (their landmarks keep their other observations;
   OKVIS-style, to keep the graph sparse), and its other factors (motion factors,
   earlier marginals) are eliminated into a linear marginal factor on the keys they
   share with the rest of the window (``LinearContainerFactor``) -- or dropped, for
   per-keyframe priors; then the source's :meth:`~.motion.MotionFactorSource.after_marginalisation`
   factors are added. Memory is bounded by the window.

Query (:meth:`LandmarkWindow.query`, :mod:`.query`): the metric points a frame sees.
:meth:`LandmarkWindow.world_landmarks`: the window's landmarks in the world frame with
their covariances. :meth:`LandmarkWindow.snapshot`: a read-only copy of the state
(:mod:`.snapshot`), e.g. for a window kept in a worker process (:mod:`.backend`).

A numerical failure inside gtsam that leaves the window unusable (an indeterminant
marginalisation, a refinement that is not finite) raises
:class:`~vio_core.errors.NumericalError`: drop the window.
"""

from __future__ import annotations

import copy
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from triangulation.multiview import MultiviewPoints, TrackStatus
from vio_core.camera import Camera
from vio_core.errors import InputError, NumericalError, SettingsError
from vio_core.geometry import invert_transform

from .covariance import PoseCovariances, prior_covariance
from .graph import WindowGraph, select_landmarks
from .incremental import triangulate_window
from .isam import IsamGraph
from .motion import MotionFactorSource, PosePriorFactors
from .query import query_frame
from .settings import LandmarkSettings
from .snapshot import WindowSnapshot, world_landmarks_of
from .tracks import Observations, TrackTable
from .types import KeyframeInput, LandmarkPoints, WindowUpdate, WorldLandmarks


@dataclass
class _Keyframe:
    info: KeyframeInput
    extra_keys: list


class LandmarkWindow:
    """gtsam sliding window over keyframes (see the module docstring).

    Args:
        settings: :class:`LandmarkSettings` (``pose_prior`` resolved).
        motion_factors: the :class:`~.motion.MotionFactorSource` of the keyframes' motion, or
            None: :class:`~.motion.PosePriorFactors` from ``settings.pose_prior``.

    Raises:
        TypeError: ``motion_factors`` does not implement :class:`~.motion.MotionFactorSource`.
    """

    def __init__(self, settings: LandmarkSettings = LandmarkSettings(), motion_factors: MotionFactorSource | None = None):
        self.settings = settings
        if settings.pose_prior is None:
            raise SettingsError("LandmarkSettings.pose_prior is not resolved: use settings.resolved(pose_kind) "
                                "(the pipeline takes the sequence's kind of poses)")
        if motion_factors is None:
            motion_factors = PosePriorFactors(settings.pose_prior)
        elif not isinstance(motion_factors, MotionFactorSource):
            raise TypeError(f"landmarks: {type(motion_factors).__name__} is not a MotionFactorSource "
                            "(provides_poses, keep_marginals, extra_keys, factors, after_marginalisation)")
        self.motion_factors: MotionFactorSource = motion_factors
        self.tracks = TrackTable()
        self._kf: OrderedDict[int, _Keyframe] = OrderedDict()
        self._graph = IsamGraph() if settings.solver == "isam2" else WindowGraph()
        self._cov = PoseCovariances()
        self._landmarks: MultiviewPoints | None = None
        self._obs: Observations | None = None  # observations behind self._landmarks
        self._pre = None  # (observations, MultiviewPoints) before the refinement in progress

    # ------------------------------------------------------------------ state
    @property
    def keyframe_ids(self) -> list[int]:
        """Frame ids of the window's keyframes, oldest first."""
        return list(self._kf)

    def keyframe(self, frame_id: int) -> KeyframeInput:
        return self._kf[frame_id].info

    def pose(self, frame_id: int) -> np.ndarray:
        """(4, 4) refined camera-to-world pose of a keyframe of the window."""
        return self._graph.pose(frame_id)

    def pose_covariance(self, frame_id: int) -> np.ndarray:
        """(6, 6) marginal covariance of a keyframe's pose in the world (rotation rad, translation m)."""
        return self._cov.pose(frame_id)

    def relative_covariances(self, reference: int | None = None) -> np.ndarray:
        """(K, 6, 6) covariance of every keyframe pose given the ``reference`` keyframe's
        (default: the newest; :meth:`~.covariance.PoseCovariances.relative`)."""
        return self._cov.relative(reference)

    def joint_covariance(self, frame_ids) -> np.ndarray:
        """(6K, 6K) joint marginal covariance of the poses of keyframes ``frame_ids`` (in that order)."""
        return self._cov.joint(frame_ids)

    @property
    def estimate(self):
        """The window's current ``gtsam.Values`` (a copy)."""
        return self._graph.copy_values()

    def landmarks(self) -> MultiviewPoints | None:
        """The last multi-view solution over the window (tracks with >= 2 observations)."""
        return self._landmarks

    def observations(self) -> Observations | None:
        """The observations behind :meth:`landmarks` (rows of its ``obs_track``), or None."""
        return self._obs

    def world_landmarks(self) -> WorldLandmarks:
        """The window's VALID landmarks in the world frame (metres) with their marginal
        covariances (square metres), as of the last keyframe insertion; empty before any."""
        return world_landmarks_of(self._landmarks)

    def snapshot(self) -> WindowSnapshot:
        """A read-only copy of the window's state as it is now (:class:`~.snapshot.WindowSnapshot`:
        the same read methods; it pickles, e.g. to leave a worker process)."""
        ids = self.keyframe_ids
        return WindowSnapshot(self.settings, {f: replace(k.info, matches=()) for f, k in self._kf.items()},
                              np.stack([self.pose(f) for f in ids]) if ids else np.zeros((0, 4, 4)),
                              copy.deepcopy(self._cov), self._graph.non_landmark_values(), self._landmarks,
                              self._obs, copy.deepcopy(self.tracks))

    def factor_count(self) -> int:
        """Non-visual factors held (priors, motion and marginal factors): bounded by the window."""
        return len(self._graph.factors)

    # ------------------------------------------------------------------ keyframes
    def add_keyframe(self, kf: KeyframeInput, initial: Any | None = None) -> WindowUpdate:
        """Insert a keyframe, refine the window, marginalise the oldest keyframe beyond it.

        Args:
            kf: the keyframe (ids increasing).
            initial: the motion source's own initial state for it, passed to
                :meth:`~.motion.MotionFactorSource.factors` unchanged (e.g. an odometry
                initialisation's), or None.

        Returns:
            :class:`WindowUpdate`; status ``refused`` (with the reason, the window unchanged)
            when the motion source has no factors for the keyframe.

        Raises:
            NumericalError: gtsam failed in a way that leaves the window unusable.
        """
        from gtsam.symbol_shorthand import X

        fid = int(kf.frame_id)
        if fid in self._kf or (self._kf and fid <= next(reversed(self._kf))):
            raise InputError(f"landmarks: keyframe ids must increase, got {fid} after {self.keyframe_ids}")
        p = self.settings.pose_prior
        prev = self._kf[next(reversed(self._kf))].info if self._kf else None
        motion = self.motion_factors.factors(prev, kf, self._graph.values, initial)
        if not motion.ok:
            return WindowUpdate.refused(fid, len(self._kf), motion.reason)
        if not motion.initial.exists(X(fid)):
            raise InputError(f"landmarks: keyframe {fid} has no pose prior and no motion factor gave one")
        self._graph.add_factors(motion.graph)
        self._graph.values.insert(motion.initial)
        self._kf[fid] = _Keyframe(kf, list(self.motion_factors.extra_keys(fid)))
        step = 0.0 if prev is None or prev.T_w_c is None or kf.T_w_c is None else float(
            np.linalg.norm((invert_transform(prev.T_w_c) @ kf.T_w_c)[:3, 3]))
        # joint covariance before refinement: the new pose is the previous one plus the
        # relative prior's uncertainty (the first one: its absolute prior)
        if prev is None:
            a, t = np.radians(p.absolute_rotation_deg), p.absolute_translation_m
            self._cov.append(fid, np.diag([a * a] * 3 + [t * t] * 3), relative=False)
        else:
            self._cov.append(fid, prior_covariance(p, step), relative=True)
        self.tracks.add_frame(fid, kf.keypoints, list(kf.matches))

        update = self._optimise(fid)
        shift = self._pose_shift_sigmas()
        marg = None
        if len(self._kf) > self.settings.window_keyframes:
            marg = next(iter(self._kf))
            self._marginalise(marg)
            # the source may re-anchor the unobservable directions (VIO: yaw and position) on
            # the new oldest keyframe, so that the window cannot drift along them
            self._graph.add_factors(self.motion_factors.after_marginalisation(next(iter(self._kf)),
                                                                              self._graph.values))
        # the landmarks of the (possibly shrunk) window at the refined poses and covariances:
        # every track seen by the newest refresh_keyframes keyframes; the others keep their
        # triangulation from before the refinement unless they changed
        _, lm = self._triangulate(self._pre, self.keyframe_ids[-self.settings.refresh_keyframes:])
        self._pre = None
        self._landmarks = lm
        good = lm.inlier & lm.valid[lm.obs_track]
        return WindowUpdate(**{**update.__dict__, "marginalised": marg, "keyframes": len(self._kf),
                               "landmarks": int(lm.valid.sum()), "pose_shift_sigmas": shift,
                               "median_residual_px": float(np.median(lm.residual_px[good])) if good.any()
                               else float("nan")})

    # ------------------------------------------------------------------ optimisation
    def _triangulate(self, previous=None, fresh_frames=(), gate_frame: int | None = None):
        """Triangulate the window's tracks (min_track_length observations or more).

        ``previous``: ``(observations, MultiviewPoints)`` of an earlier triangulation, or
        None. Its result is kept for the tracks whose observations did not change since
        and that have no observation in a keyframe of ``fresh_frames``; the others are
        triangulated at the current poses and covariances (:mod:`.incremental`) -- except,
        with ``gate_frame``, the tracks that only gained an observation in that keyframe
        (:func:`~.incremental.gate_extensions`).
        """
        ids = self.keyframe_ids
        obs, res = triangulate_window(self.tracks, ids, [self._kf[f].info.camera for f in ids],
                                      np.stack([self.pose(f) for f in ids]), self.relative_covariances(),
                                      self.settings.multiview, self.settings.min_track_length, previous, fresh_frames,
                                      gate_frame)
        self._obs = obs
        return obs, res

    def _optimise(self, new_id: int) -> WindowUpdate:
        s = self.settings
        if s.pose_prior.absolute_on_every_keyframe and s.restart_from_priors:
            # every refinement starts from the priors: a window that went astray (e.g. while
            # it had too few keyframes to fix the scale) does not carry its error forward
            for f, k in self._kf.items():
                if k.info.T_w_c is not None:
                    self._graph.set_pose(f, k.info.T_w_c)
        # the tracks the new keyframe did not change keep the last update's triangulation
        previous = None if self._landmarks is None else (self._obs, self._landmarks)
        obs, mv = self._triangulate(previous, [new_id], new_id if s.gate_extended_tracks else None)
        self._pre = (obs, mv)
        # per-track outlier rejection: observations outside the gate leave their track
        out = ~mv.inlier & (mv.status[mv.obs_track] != TrackStatus.TOO_FEW_VIEWS)
        out &= np.isin(mv.status[mv.obs_track], (TrackStatus.VALID, TrackStatus.UNCERTAIN, TrackStatus.DEPTH_RANGE))
        detached = int(out.sum())
        if detached:
            self.tracks.detach(obs.frame[out], obs.keypoint[out])
        in_graph = select_landmarks(mv, s)
        use = mv.inlier & in_graph[mv.obs_track]
        cameras = {f: k.info.camera for f, k in self._kf.items()}
        ref = self._graph.refine(cameras, obs, mv, use, in_graph, s)
        if not all(np.all(np.isfinite(self.pose(f))) for f in self._kf):
            raise NumericalError("landmarks: the refined keyframe poses are not finite")
        if ref.joint_covariance is not None:
            self._cov.set(ref.joint_covariance)
        return WindowUpdate(new_id, len(self._kf), 0, ref.observations, detached, None,
                            mv.status_counts(), ref.error_before, ref.error_after)

    def _pose_shift_sigmas(self) -> float:
        p = self.settings.pose_prior
        sig = np.array([np.radians(p.absolute_rotation_deg)] * 3 + [p.absolute_translation_m] * 3)
        ids = [f for f, k in self._kf.items() if k.info.T_w_c is not None]
        if not ids:
            return 0.0
        # every keyframe's shift from its prior at once (one rotation conversion for all)
        d = np.stack([invert_transform(self._kf[f].info.T_w_c) @ self.pose(f) for f in ids])
        shift = np.concatenate([Rotation.from_matrix(d[:, :3, :3]).as_rotvec(), d[:, :3, 3]], axis=1) / sig
        worst = 0.0
        for v in np.sqrt(np.mean(shift**2, axis=1)).tolist():
            worst = max(worst, v)
        return worst

    def _marginalise(self, frame_id: int) -> None:
        """Marginalise a keyframe: drop its projections, eliminate (or drop) its other factors."""
        from gtsam.symbol_shorthand import X

        self._graph.marginalise({X(frame_id), *self._kf[frame_id].extra_keys}, self.motion_factors.keep_marginals)
        self._cov.remove(frame_id)
        self._kf.pop(frame_id)
        self.tracks.remove_frame(frame_id)

    # ------------------------------------------------------------------ query
    def query(self, camera: Camera, T_w_c, keypoints, matches=(), frame_id: int | None = None,
              prior_covariance=None) -> LandmarkPoints:
        """Metric landmark points seen by a frame (:func:`~.query.query_frame`).

        Args:
            camera: the frame's camera.
            T_w_c: (4, 4) the frame's pose prior (camera-to-world, metres), or None for a
                keyframe of the window (its refined pose is used).
            keypoints: (N, 2) raw pixels of the frame's keypoints.
            matches: :class:`FrameMatches` with keyframes of the window (not needed for a
                keyframe of the window).
            frame_id: the frame's id; when it is a keyframe of the window its
                observations are read directly.
            prior_covariance: (6, 6) covariance of ``T_w_c`` relative to the newest matched
                keyframe (e.g. an IMU prediction's), or None: the relative pose prior of the
                settings.

        Returns:
            :class:`LandmarkPoints` (possibly empty, with a reason).
        """
        return query_frame(self, camera, T_w_c, keypoints, matches, frame_id, prior_covariance)
