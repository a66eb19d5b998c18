"""The camera pose the run itself has for each frame: the only pose its outputs may use.

Every output of a run -- the depth maps, ``frames.jsonl``, ``trajectory.tum``, the PLY
clouds, the report, the MCAP / rosbag2 export, the Rerun recording and any later export --
receives its frames through :meth:`OutputPoses.output_frame`: the frame with ``T_w_c``
replaced by the run's own pose of it (None when the run has none) and the dataset's
``velocity_w`` removed. An output therefore cannot read a pose the run did not use, whatever
the sequence holds. Which pose is the run's depends on the pose source:

* ``--poses gt`` (:class:`~vio_depth.poses.GroundTruthPoses`): the sequence's poses *are*
  the pose source, so the frame's sequence pose (calibrated with ``--calibrate-poses``);
  the frame keeps it unchanged.
* a tracking source (``--poses vio``): the pose the points stage used (the landmark
  window's), else the odometry's pose of the frame when it was processed
  (``FrameResult.frame_pose``, only when ``ok``). A sequence pose is never read.
* any other source (``--poses imu``: relative poses): the pose the points stage used, else
  the source's relative pose to the frame's first partner keyframe applied to the
  keyframe's anchor -- its sequence pose (the state the IMU source propagates from), else
  the run's own earlier pose of the keyframe, else the identity for the run's first frame
  when the sequence has no poses at all. This is the rule of ``trajectory.tum``
  (:func:`~vio_depth.run.trajectory.used_poses`) applied as the frames are written.

The poses are those known when a frame is written: with ``--poses vio`` ``trajectory.tum``
holds the odometry's later, smoothed estimates (read at the end of the run), which may
differ from the per-frame clouds' placement by the smoother's correction.

The sequence's poses are read elsewhere only to *evaluate* the run, and only into fields
labelled as such: ``metrics.json`` ``trajectory.ate``, ``trajectory.rpe``,
``trajectory.reference_poses`` and ``trajectory.note`` (:func:`~vio_depth.run.trajectory.run_trajectory`),
and, under ``--poses gt`` only, the ``--calibrate-poses`` pre-pass (``pose_calibration``:
it calibrates the poses the run then uses). ``tests/vio_depth/run/test_pose_leak.py`` checks it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..frame import Frame
from ..io import Sequence
from ..pipeline import FrameResult, Pipeline
from ..poses import GroundTruthPoses


class OutputPoses:
    """The run's own camera-to-world pose of each frame, as the frames are written (module docstring).

    Args:
        sequence: the run's sequence (read for keyframe anchors only by a relative pose source).
        pipeline: the run's pipeline (its pose source decides the rule).
        n: the number of frames the run processes.

    Call :meth:`output_frame` once per written frame, in the order the run writes them
    (forward frames in order, then the backward pass's frames, latest first).
    """

    def __init__(self, sequence: Sequence, pipeline: Pipeline, n: int):
        self.sequence = sequence
        self.sequence_poses = isinstance(pipeline.pose_source, GroundTruthPoses)
        self.tracking = pipeline.tracker is not None
        self._poses: dict[int, np.ndarray] = {}  # frame index -> the run's pose (relative sources)
        self._origin: int | None = None
        self._n = n
        self._sequence_has_poses: bool | None = None  # relative sources: looked up once, when first needed

    def pose(self, frame: Frame, result: FrameResult) -> np.ndarray | None:
        """(4, 4) camera-to-world pose, metres, the run has for ``frame`` (with ``result``), or None."""
        if self.sequence_poses:
            return frame.T_w_c
        if result.points.T_w_c is not None:
            T = np.asarray(result.points.T_w_c, dtype=np.float64)
        elif self.tracking:
            fp = result.frame_pose
            T = None if fp is None or not fp.ok or fp.T_w_c is None else np.asarray(fp.T_w_c, dtype=np.float64)
        else:
            T = self._chained(frame, result)
        if T is not None and not self.tracking:
            self._poses[frame.index] = T
        return T

    def _chained(self, frame: Frame, result: FrameResult) -> np.ndarray | None:
        if self._origin is None:
            self._origin = frame.index
        pair = result.points.relative_pose
        if pair is None:
            return None
        k, T_kf_cur = pair
        T_w_kf = self._anchor(k)
        return None if T_w_kf is None else T_w_kf @ np.asarray(T_kf_cur, dtype=np.float64)

    def _anchor(self, k: int) -> np.ndarray | None:
        """Keyframe ``k``'s pose: its sequence pose, the run's own, or the origin's identity."""
        T = self.sequence[k].T_w_c
        if T is not None:
            return np.asarray(T, dtype=np.float64)
        if k in self._poses:
            return self._poses[k]
        if k == self._origin:
            if self._sequence_has_poses is None:
                self._sequence_has_poses = any(self.sequence[i].T_w_c is not None for i in range(self._n))
            return None if self._sequence_has_poses else np.eye(4)
        return None

    def output_frame(self, frame: Frame, result: FrameResult) -> Frame:
        """``frame`` as the outputs see it: ``T_w_c`` the run's own pose (:meth:`pose`), no ``velocity_w``."""
        if self.sequence_poses:
            return frame
        return replace(frame, T_w_c=self.pose(frame, result), velocity_w=None)
