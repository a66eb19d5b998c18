"""The odometry's own landmarks per frame, kept for the points stage (``--points vio``).

The landmark window of the odometry refines metric landmarks with covariances for every
frame it tracks (:meth:`~vio_depth.landmarks.LandmarkEstimator.process`: the frame's
keypoints associated with landmarks, their depths in the frame and the depths' 1-sigma
from the landmarks' marginal covariances and the frame's pose covariance). The
:class:`LandmarkLog` keeps them per frame (bounded, like the pose history), with how well
the window knew its metric scale at that moment, so that a points stage reads them
instead of matching and triangulating the frame again -- also on the offline backward
pass, which hands the first frames over a second time.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from vio_core.camera import Camera

from ..landmarks import LandmarkEstimator, LandmarkPoints, WindowUpdate


@dataclass(frozen=True)
class OdometryLandmarks:
    """The landmarks the odometry saw in one frame.

    Attributes:
        frame_id: the frame.
        points: :class:`~vio_depth.landmarks.LandmarkPoints`: ``uv`` (N, 2) raw pixels,
            ``depth`` (N,) metres (camera z), ``sigma_depth`` (N,) metres (1-sigma from the
            landmarks' marginal covariances and the frame's pose covariance),
            ``covariance`` (6, 6) of the frame's pose relative to the window's newest keyframe
            (rotation rad, translation m; right perturbation), ``T_w_c`` (4, 4) the frame's
            pose in the odometry's world.
        keyframe: the frame became a keyframe of the window; ``keyframe_reason`` why.
        matches: its feature matches with the window's keyframes (summed).
        window_keyframes: keyframes in the window after the frame.
        scale_sigma: relative 1-sigma of the window's metric scale when the points were read
            (``sigma / distance`` of :meth:`~vio_depth.vio.PoseHistory.window_span_sigma`;
            0 for a one-keyframe window).
        update: the window update when the frame became a keyframe, else None.
    """

    frame_id: int
    points: LandmarkPoints
    keyframe: bool
    keyframe_reason: str
    matches: int
    window_keyframes: int
    scale_sigma: float
    update: WindowUpdate | None = None


def relative_scale_sigma(sigma_m: float, distance_m: float) -> float:
    """``sigma / distance`` of a window span (inf without a window, 0 for a single keyframe)."""
    if distance_m > 0:
        return float(sigma_m / distance_m)
    return 0.0 if sigma_m == 0 else float("inf")


#: frames whose landmarks the odometry keeps: the current one, and enough for the offline
#: backward pass over a start and its convergence (a few MB: about 50 kB per frame of 1000
#: landmarks); memory stays flat however long the run
KEPT_FRAMES = 256


class LandmarkLog:
    """The :class:`OdometryLandmarks` of the last ``capacity`` frames the odometry tracked.

    Args:
        capacity: frames kept (oldest dropped first).
    """

    def __init__(self, capacity: int):
        self.capacity = int(capacity)
        self._frames: OrderedDict[int, OdometryLandmarks] = OrderedDict()

    def __len__(self) -> int:
        return len(self._frames)

    def get(self, frame_id: int) -> OdometryLandmarks | None:
        """The landmarks of frame ``frame_id``, or None (not tracked, or forgotten)."""
        return self._frames.get(int(frame_id))

    def record(self, frame_id: int, frame_landmarks, window_keyframes: int, scale_sigma: float) -> None:
        """Keep a frame's :class:`~vio_depth.landmarks.FrameLandmarks` (its match arrays are not kept)."""
        fl = frame_landmarks
        self._put(OdometryLandmarks(int(frame_id), fl.points, bool(fl.keyframe), fl.keyframe_reason, int(fl.matches),
                                    int(window_keyframes), float(scale_sigma), fl.update))

    def record_window_keyframes(self, landmarks: LandmarkEstimator, frames: list[tuple[int, Camera, np.ndarray]],
                                scale_sigma: float, reason: str) -> None:
        """Keep the landmarks of keyframes of the window read from the window itself (the
        keyframes of an initialisation, once the window is refined).

        ``frames``: ``(frame id, camera, keypoints (K, 2) raw pixels)`` of each keyframe.
        """
        w = landmarks.window
        for frame_id, camera, keypoints in frames:
            if frame_id not in w.keyframe_ids:
                continue
            pts = w.query(camera, None, keypoints, frame_id=frame_id)
            self._put(OdometryLandmarks(int(frame_id), pts, True, reason, 0, len(w.keyframe_ids), float(scale_sigma)))

    def _put(self, item: OdometryLandmarks) -> None:
        self._frames[item.frame_id] = item
        self._frames.move_to_end(item.frame_id)
        while len(self._frames) > self.capacity:
            self._frames.popitem(last=False)
