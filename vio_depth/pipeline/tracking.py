"""Features from a tracking matcher (:class:`matchers.FrameTracker`, e.g. KLT), with the
camera's rotation since the previous frame as its prediction.

A tracker follows the previous frame's corners, so :class:`TrackedExtraction` hands it the
frames in order and tells it the rotation between them: under ``--poses gt`` from the
sequence's own poses (the pose source's input), under any other source from the
gyroscope (:func:`~vio_depth.poses.gyro.camera_rotation`; the ground truth a sequence may
carry is for evaluation only). Frames may also come in reverse order, one by one (the offline
backward pass re-tracks the first frames from later ones). A frame that is not the previous
one's neighbour (a resumed run, a gap) restarts the tracks; track ids keep increasing, so
features of before and after never join.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from matchers import Features, FrameTracker, MotionHint

from ..frame import Frame, ImuData
from ..poses.gyro import camera_rotation


class TrackedExtraction:
    """Each frame's features from ``tracker``, in order (module docstring).

    Args:
        tracker: the tracking matcher.
        imu_of: returns the IMU samples known so far (None without an IMU); read at each frame
            (a stream's samples grow).
        use_poses: take the rotation from the frames' own poses (``--poses gt``) rather than
            the gyroscope.
    """

    def __init__(self, tracker: FrameTracker, imu_of: Callable[[], ImuData | None], use_poses: bool):
        self.tracker = tracker
        self.imu_of = imu_of
        self.use_poses = use_poses
        self._prev: Frame | None = None

    def rotation(self, prev: Frame, frame: Frame) -> np.ndarray | None:
        """(3, 3) ``R_cur_prev`` of ``prev`` into ``frame``'s camera (either may be the
        earlier one), or None when unknown."""
        if self.use_poses:
            if prev.T_w_c is None or frame.T_w_c is None:
                return None
            return np.asarray(frame.T_w_c, float)[:3, :3].T @ np.asarray(prev.T_w_c, float)[:3, :3]
        imu = self.imu_of()
        if imu is None:
            return None
        if frame.timestamp >= prev.timestamp:
            return camera_rotation(imu, prev.timestamp, frame.timestamp)
        R = camera_rotation(imu, frame.timestamp, prev.timestamp)  # R_prev_cur: backwards in time
        return None if R is None else R.T

    @staticmethod
    def follows(prev: Frame | None, frame: Frame) -> bool:
        """Whether ``frame`` is ``prev``'s neighbour, forwards or backwards (its tracks continue)."""
        if prev is None:
            return False
        step = frame.index - prev.index
        dt = frame.timestamp - prev.timestamp
        return (step == 1 and dt > 0) or (step == -1 and dt < 0)

    def __call__(self, frame: Frame, image: np.ndarray) -> Features:
        """The features of ``frame`` (whose pixels are ``image``)."""
        prev, self._prev = self._prev, frame
        if not self.follows(prev, frame):
            self.tracker.reset()
            return self.tracker.track(image, MotionHint(frame.camera))
        return self.tracker.track(image, MotionHint(frame.camera, self.rotation(prev, frame)))
