"""The pose-camera calibration of a run (``--calibrate-poses auto|off``).

Before the frame loop, :func:`calibrate_run_poses` estimates the time offset and
camera-to-body transform between the sequence's poses and its camera from a subset of the
run's frames (:func:`vio_depth.poses.estimate_pose_calibration`: about 30 anchors, each
paired with the frames 0.1, 0.2 and 0.3 s later, so at most ~120 images are matched). When
the estimate is applied, the run reads the sequence through :class:`PoseCalibratedSequence`,
whose frames carry the corrected camera poses ``T_w_b(t + dt) T_b_c``; everything
downstream (pairing, triangulation, landmarks' priors, ``trajectory.tum``) sees those.

Skipped, with the reason in ``metrics.json``, for ``--calibrate-poses off``, exact poses
(rendered samples: their poses are the camera's), pose sources other than the sequence's
own (``--poses imu`` / ``vio``), and point sources that match no images.
"""

from __future__ import annotations

import logging
from dataclasses import replace

from ..frame import Frame
from ..io import Sequence
from ..pipeline import Pipeline
from ..poses import GroundTruthPoses, PoseCalibration, PoseTimeline, calibrated_poses, estimate_pose_calibration
from .config import RunSettings

log = logging.getLogger(__name__)


def calibrate_run_poses(sequence: Sequence, pipeline: Pipeline, settings: RunSettings, n: int) -> PoseCalibration:
    """The pose-camera calibration for a run of ``sequence``'s first ``n`` frames (skipped,
    with a reason, where it does not apply; see the module docstring)."""
    if settings.calibrate_poses == "off":
        return PoseCalibration.skipped("--calibrate-poses off")
    if not isinstance(pipeline.pose_source, GroundTruthPoses):
        return PoseCalibration.skipped(f"the poses come from the {pipeline.pose_source.name!r} pose source, "
                                       "not the sequence (--poses gt)")
    if sequence.pose_kind == "exact":
        return PoseCalibration.skipped("exact poses")
    if pipeline.matcher is None:
        return PoseCalibration.skipped("the points do not come from the images (no matcher)")
    calibration = estimate_pose_calibration([sequence.frame(i) for i in range(n)], pipeline.matcher,
                                            settings.pose_calibration)
    log.info("%s", calibration.summary())
    return calibration


class PoseCalibratedSequence(Sequence):
    """``inner`` with every frame's ``T_w_c`` replaced by the calibrated camera pose
    (:func:`vio_depth.poses.calibrated_poses` on the poses of ``inner``'s first ``n`` frames;
    later frames and frames without a pose keep theirs)."""

    def __init__(self, inner: Sequence, calibration: PoseCalibration, n: int):
        super().__init__(inner.root, inner.name, inner.camera, inner.imu, inner.disparity)
        self.inner = inner
        self.calibration = calibration
        self.format_name = inner.format_name
        self.imu_missing_reason = inner.imu_missing_reason
        self.pose_kind = inner.pose_kind
        frames = [inner.frame(i) for i in range(n)]
        posed = [f for f in frames if f.T_w_c is not None]
        timeline = PoseTimeline([f.timestamp for f in posed], [f.T_w_c for f in posed])
        corrected = calibrated_poses(timeline, [f.timestamp for f in posed], calibration)
        self._poses = {f.index: T for f, T in zip(posed, corrected)}

    def __len__(self) -> int:
        return len(self.inner)

    @property
    def has_gt_depth(self) -> bool:
        return self.inner.has_gt_depth

    def frame(self, index: int) -> Frame:
        frame = self.inner.frame(index)
        T = self._poses.get(frame.index)
        return frame if T is None else replace(frame, T_w_c=T.copy())


def calibrated_sequence(sequence: Sequence, calibration: PoseCalibration, n: int) -> Sequence:
    """``sequence`` seen with the calibrated poses, or itself when the calibration is not applied."""
    return PoseCalibratedSequence(sequence, calibration, n) if calibration.applied else sequence
