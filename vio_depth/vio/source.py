"""``--poses vio``: the visual-inertial odometry as the pipeline's pose source.

A :class:`~vio_depth.poses.TrackingPoseSource`: the pipeline hands it every frame in order
with the frame's features (:meth:`VioPoseSource.track`), then asks for relative poses
between tracked frames (:meth:`VioPoseSource.relative`), each with the covariance of the
odometry (:mod:`.history`). The sequence's own poses (``Frame.T_w_c``) are **never read**:
with ``--poses vio`` they serve only to evaluate the run (ATE / RPE).

A frame handed over again (the offline backward pass of a run walks the first frames in
reverse) is not re-estimated: it gets the pose the odometry has for it now -- which,
for the frames of the initialisation, was found only after they were first seen (status
``retroactive``).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from matchers import Features, Matcher, create_matcher
from vio_core.errors import InputError

from ..frame import Frame, ImuData
from ..landmarks import ProcessWindow
from ..poses import FramePose, RelativePose
from .estimator import VioEstimator, VioFrame
from .landmark_feed import OdometryLandmarks
from .settings import VioSettings


def _frame_pose(v: VioFrame) -> FramePose:
    return FramePose(v.T_w_c, v.covariance, v.ok, v.status.value, v.reason)


class VioPoseSource:
    """Relative poses from the visual-inertial odometry (module docstring).

    Args:
        imu: the IMU samples (with ``T_c_i``).
        matcher: the matcher that extracts the features handed to :meth:`track`.
        settings: :class:`~vio_depth.vio.VioSettings`.
        backend: the landmark window's worker, started early (:class:`VioEstimator`), or None.
    """

    name = "vio"

    def __init__(self, imu: ImuData, matcher: Matcher, settings: VioSettings = VioSettings(),
                 backend: ProcessWindow | None = None):
        self.settings = settings
        self.matcher = matcher
        self.estimator = VioEstimator(imu, matcher, settings, backend)
        self._results: OrderedDict[int, FramePose] = OrderedDict()
        self._last: int | None = None
        self._main_session: tuple[int, int | None] | None = None  # (history size, session)

    @classmethod
    def for_sequence(cls, sequence, settings: VioSettings = VioSettings(), matcher: Matcher | None = None):
        """The source for ``sequence`` (its IMU). Raises :class:`InputError` without IMU samples."""
        cls.check_sequence(sequence)
        return cls(sequence.imu, create_matcher("sift") if matcher is None else matcher, settings)

    @staticmethod
    def check_sequence(sequence) -> None:
        """Raises :class:`InputError` when ``sequence`` has no IMU samples."""
        if getattr(sequence, "imu", None) is None:
            why = getattr(sequence, "imu_missing_reason", "")
            raise InputError(f"{getattr(sequence, 'root', sequence)}: sequence has no IMU, so --poses vio is not "
                             f"possible{' (' + why + ')' if why else ''}")

    def update_samples(self, imu: ImuData) -> None:
        """Use ``imu`` (the samples so far plus newer ones) from now on (streaming input)."""
        self.estimator.update_samples(imu)

    def samples_needed_since(self) -> float | None:
        """Seconds before which no IMU sample is read again (:meth:`VioEstimator.samples_needed_since`)."""
        return self.estimator.samples_needed_since()

    def track(self, frame: Frame, features: Features) -> FramePose:
        """Estimate the pose of the next frame; a frame seen before gets its current pose."""
        if self._last is not None and frame.index <= self._last:
            self.estimator.bridges.settle()  # the in-between frames' poses are read: re-posed if due
            T = self.estimator.history.pose(frame.index)
            if T is not None:
                old = self._results.get(frame.index)
                if old is not None and old.ok:
                    return FramePose(T, old.covariance, True, old.status, old.reason)
                return FramePose(T, None, True, "retroactive", "posed by the odometry after this frame was processed "
                                                               "(its initialisation, or while its scale converged)")
            old = self._results.get(frame.index)
            return old if old is not None else FramePose(None, ok=False, status="unknown",
                                                         reason="frame not tracked by the odometry")
        self._last = frame.index
        result = _frame_pose(self.estimator.process(frame.index, frame.timestamp, frame.camera, features))
        self._results[frame.index] = result
        while len(self._results) > self.settings.history_frames:
            self._results.popitem(last=False)
        return result

    def finish(self) -> None:
        """The sequence ended (offline): the odometry takes over what its window's worker still
        has (:meth:`VioEstimator.finish`); the frames it poses then answer :meth:`track` again as
        ``retroactive`` (the backward pass)."""
        self.estimator.finish()

    def world_pose(self, frame: Frame) -> np.ndarray | None:
        """(4, 4) the odometry's latest camera-to-world pose of a tracked frame, or None.

        Only frames of the odometry's main session (the one with the most posed frames)
        have one: after a re-initialisation the world frame is a new one.
        """
        self.estimator.bridges.settle()
        history = self.estimator.history
        if self._main_session is None or self._main_session[0] != len(history):
            sessions = history.sessions()
            self._main_session = (len(history), max(sessions, key=sessions.get) if sessions else None)
        if history.session(frame.index) != self._main_session[1]:
            return None
        return history.pose(frame.index)

    def frame_landmarks(self, frame: Frame) -> OdometryLandmarks | None:
        """The odometry's metric landmarks seen in a tracked ``frame`` with their depth
        1-sigma (:meth:`VioEstimator.frame_landmarks`), or None."""
        return self.estimator.frame_landmarks(frame.index)

    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        """``T_kf_cur`` and its (6, 6) covariance (right perturbation in the current camera)."""
        self.estimator.bridges.settle()
        T, C, reason = self.estimator.history.relative(keyframe.index, current.index)
        if T is None:
            return RelativePose(None, ok=False, reason=reason)
        return RelativePose(T, C)
