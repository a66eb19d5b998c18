"""A read-only copy of the landmark window's state: :class:`WindowSnapshot`.

:meth:`LandmarkWindow.snapshot <vio_depth.landmarks.window.LandmarkWindow.snapshot>` takes
it after a keyframe update. It answers every read of the window (keyframes, poses, their
joint covariance, the landmarks and their observations, the tracks, the estimate, a
frame's query) exactly as the window did when it was taken, and it pickles: a window that
lives in a worker process (:mod:`.backend`) sends one back after each keyframe, and the
frames that follow are matched, queried and posed against it.

:meth:`WindowSnapshot.with_keyframe` extends a snapshot by a keyframe whose update is still
being computed (in the worker): its matches join the tracks and the tracks it touched are
triangulated at its estimated pose and that pose's uncertainty, without a refinement -- a
*provisional* window that the frames meanwhile are matched and queried against.
"""

from __future__ import annotations

import copy

import numpy as np

from triangulation.multiview import MultiviewPoints
from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError

from .covariance import PoseCovariances
from .incremental import triangulate_window
from .query import query_frame
from .settings import LandmarkSettings
from .tracks import Observations, TrackTable
from .types import KeyframeInput, LandmarkPoints, WorldLandmarks


def world_landmarks_of(lm: MultiviewPoints | None) -> WorldLandmarks:
    """The VALID landmarks of a multi-view solution in the world frame (metres), with their
    marginal covariances (square metres); empty for None."""
    if lm is None:
        return WorldLandmarks(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0, np.int64))
    v = lm.valid
    return WorldLandmarks(lm.track_ids[v].astype(np.int64), lm.points_w[v], lm.covariance_w[v],
                          lm.n_inliers[v].astype(np.int64))


class WindowSnapshot:
    """The window's state after an update (module docstring); the same read methods.

    Args:
        settings: the window's :class:`LandmarkSettings`.
        keyframes: the keyframes' inputs by frame id, oldest first (their matches dropped).
        poses: (K, 4, 4) refined camera-to-world poses of ``keyframes``, metres.
        covariances: the keyframe poses' joint covariance (:class:`~.covariance.PoseCovariances`).
        estimate: ``gtsam.Values`` of the window's non-landmark keys (poses, the motion
            source's keys).
        landmarks / observations: the last multi-view solution and its observations, or None.
        tracks: the window's :class:`~.tracks.TrackTable` (not to be modified).
        reference: the keyframe that :meth:`relative_covariances` is relative to by default
            (None: the newest).
    """

    def __init__(self, settings: LandmarkSettings, keyframes: dict[int, KeyframeInput], poses: np.ndarray,
                 covariances: PoseCovariances, estimate, landmarks: MultiviewPoints | None,
                 observations: Observations | None, tracks: TrackTable, reference: int | None = None):
        self.settings = settings
        self._kf = dict(keyframes)
        self._poses = {f: np.array(T, np.float64) for f, T in zip(self._kf, poses)}
        self._cov = covariances
        self._estimate = estimate
        self._landmarks = landmarks
        self._obs = observations
        self.tracks = tracks
        self._reference = reference

    @classmethod
    def empty(cls, settings: LandmarkSettings, estimate=None) -> "WindowSnapshot":
        """A window without keyframes (``estimate``: an empty ``gtsam.Values``, or None)."""
        return cls(settings, {}, np.zeros((0, 4, 4)), PoseCovariances(), estimate, None, None, TrackTable())

    @property
    def keyframe_ids(self) -> list[int]:
        """Frame ids of the window's keyframes, oldest first."""
        return list(self._kf)

    def keyframe(self, frame_id: int) -> KeyframeInput:
        return self._kf[frame_id]

    def pose(self, frame_id: int) -> np.ndarray:
        """(4, 4) refined camera-to-world pose of a keyframe, metres (a copy)."""
        return self._poses[frame_id].copy()

    def pose_covariance(self, frame_id: int) -> np.ndarray:
        """(6, 6) marginal covariance of a keyframe's pose (rotation rad, translation m)."""
        return self._cov.pose(frame_id)

    def relative_covariances(self, reference: int | None = None) -> np.ndarray:
        """(K, 6, 6) covariance of every keyframe pose given the ``reference`` keyframe's (default:
        the snapshot's reference keyframe, the newest unless it was extended by :meth:`with_keyframe`)."""
        return self._cov.relative(self._reference if reference is None else reference)

    def joint_covariance(self, frame_ids) -> np.ndarray:
        """(6K, 6K) joint marginal covariance of the poses of keyframes ``frame_ids`` (in that order)."""
        return self._cov.joint(frame_ids)

    @property
    def estimate(self):
        """The window's ``gtsam.Values`` of its non-landmark keys (a copy)."""
        import gtsam

        return gtsam.Values(self._estimate)

    def landmarks(self) -> MultiviewPoints | None:
        return self._landmarks

    def observations(self) -> Observations | None:
        return self._obs

    def world_landmarks(self) -> WorldLandmarks:
        """The VALID landmarks in the world frame with their marginal covariances."""
        return world_landmarks_of(self._landmarks)

    def query(self, camera: Camera, T_w_c, keypoints, matches=(), frame_id: int | None = None,
              prior_covariance=None) -> LandmarkPoints:
        """Metric landmark points seen by a frame (:func:`~.query.query_frame`, as
        :meth:`LandmarkWindow.query <vio_depth.landmarks.window.LandmarkWindow.query>`)."""
        return query_frame(self, camera, T_w_c, keypoints, matches, frame_id, prior_covariance)

    def with_keyframe(self, kf: KeyframeInput, T_w_c, covariance) -> "WindowSnapshot":
        """A provisional window: this one and keyframe ``kf``, not refined (module docstring).

        ``kf``'s matches (with keyframes of this window; others are dropped) join a copy of the
        tracks; the tracks it touched are triangulated again at ``T_w_c`` (4, 4) camera-to-world
        (its estimate, metres) with ``covariance`` (6, 6) relative to this window's reference
        keyframe (rotation rad, translation m), the others keep their triangulation. The
        reference keyframe stays this window's (relative covariances, and through them the
        queries' pose covariances, stay relative to it); the estimate is this window's (it has
        no state for ``kf``).
        """
        T = check_transform("T_w_c", T_w_c)
        C = check_array("covariance", covariance, (6, 6), finite=True)
        ids = self.keyframe_ids
        fid = int(kf.frame_id)
        if not ids or fid <= ids[-1]:
            raise InputError(f"landmarks: a provisional keyframe extends a window with older keyframes, got {fid} "
                             f"after {ids}")
        reference = ids[-1] if self._reference is None else self._reference
        tracks = copy.deepcopy(self.tracks)
        tracks.add_frame(fid, kf.keypoints, [m for m in kf.matches if m.keyframe in ids])
        cov = copy.deepcopy(self._cov)
        # the covariance is relative to the reference: append it to that keyframe's, as if it
        # were the newest (the joint rows of the others follow the reference's)
        cov.append_relative_to(fid, C, reference)
        keyframes = {**self._kf, fid: KeyframeInput(fid, kf.timestamp, kf.camera, kf.T_w_c, kf.keypoints, ())}
        poses = np.stack([*(self._poses[f] for f in ids), T])
        previous = None if self._landmarks is None else (self._obs, self._landmarks)
        all_ids = [*ids, fid]
        obs, lm = triangulate_window(tracks, all_ids, [keyframes[f].camera for f in all_ids], poses,
                                     cov.relative(reference), self.settings.multiview, self.settings.min_track_length,
                                     previous, [fid])
        return WindowSnapshot(self.settings, keyframes, poses, cov, self._estimate, lm, obs, tracks, reference)
