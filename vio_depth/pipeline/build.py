"""Building a pipeline's stages from its settings, in one place, by explicit calls.

:func:`build_stages` turns a :class:`~vio_depth.pipeline.PipelineSettings` into the matcher,
the pose source, the disparity source and the points stage; :class:`~vio_depth.pipeline.Pipeline`
and :class:`~vio_depth.pipeline.FrameStream` both build through it. Each choice is one
``match`` on a settings type or kind below, over sources imported explicitly at the top of
this module: nothing is registered at import time, so ``vio-depth run --poses vio`` reads
``POSE_PRESETS["vio"]`` (a :class:`~vio_depth.vio.VioSettings`), and
:func:`build_pose_stage` builds a :class:`~vio_depth.vio.VioPoseSource` for it, whose
:class:`~vio_depth.vio.VioEstimator` the pipeline hands every frame.
"""

from __future__ import annotations

from dataclasses import dataclass

from matchers import Matcher, create_matcher
from vio_core.errors import InputError, SettingsError

from ..disparity import DisparitySource, create_disparity_source
from ..poses import (
    GroundTruthPoses,
    GroundTruthPoseSettings,
    ImuPoseSettings,
    ImuPoseSource,
    PoseSource,
    TrackingPoseSource,
    import_gtsam,
)
from ..landmarks import ProcessWindow
from ..vio import VioPoseSource, VioSettings
from .feed import LazyImuPoses, StreamInputs
from .landmark_points import LandmarkPointsStage
from .point_source import PointSourceKind
from .points import TwoViewPoints
from .settings import POSE_PRESETS, PipelineSettings, PoseSettings
from .source_landmarks import SourceLandmarkPoints
from .vio_points import VioPoints

PointsStage = TwoViewPoints | LandmarkPointsStage


@dataclass(frozen=True)
class PoseStage:
    """A pose source and whether it tracks the frames itself.

    Attributes:
        source: gives the relative poses.
        tracker: the same source when it estimates the poses from the frames (``vio``: the
            pipeline hands it every frame with its features first), else None.
        workers: the worker processes started for the source (``vio`` with a ``process``
            backend); whoever built the stage stops them (:meth:`close`).
    """

    source: PoseSource
    tracker: TrackingPoseSource | None = None
    workers: tuple[ProcessWindow, ...] = ()

    def close(self) -> None:
        """Stop the stage's worker processes (the source is unusable after it)."""
        for worker in self.workers:
            worker.close()

    @classmethod
    def of(cls, source: PoseSource) -> "PoseStage":
        """The stage of a source built elsewhere: a tracker when it implements
        :class:`~vio_depth.poses.TrackingPoseSource`."""
        return cls(source, source if isinstance(source, TrackingPoseSource) else None)


@dataclass(frozen=True)
class Stages:
    """Everything a :class:`~vio_depth.pipeline.Pipeline` runs, built by :func:`build_stages`.

    Attributes:
        matcher: extracts every frame's features; None when no stage needs features.
        poses: the pose source (:class:`PoseStage`).
        disparity_source: each frame's affine-invariant disparity.
        points: the points stage (two-view ``sfm`` or ``landmarks``); None for the reference
            sources sampled from ground truth (``lidar:N``, ``random:N``).
    """

    matcher: Matcher | None
    poses: PoseStage
    disparity_source: DisparitySource
    points: PointsStage | None

    @property
    def points_workers(self) -> tuple[ProcessWindow, ...]:
        """The worker process the points stage keeps its window in (``landmarks_backend``), if any."""
        worker = self.points.worker if isinstance(self.points, LandmarkPointsStage) else None
        return () if worker is None else (worker,)


def tracks_frames(settings: PoseSettings) -> bool:
    """Whether the pose source of ``settings`` estimates the poses from the frames (needs features)."""
    return isinstance(settings, VioSettings)


def build_pose_stage(settings: PoseSettings | str, sequence=None, matcher: Matcher | None = None, *,
                     stream: StreamInputs | None = None) -> PoseStage:
    """The pose source for ``settings`` (a settings object or a :data:`POSE_PRESETS` name).

    Args:
        settings: :class:`~vio_depth.poses.GroundTruthPoseSettings` (``gt``),
            :class:`~vio_depth.poses.ImuPoseSettings` (``imu``, ``imu_real_mav``) or
            :class:`~vio_depth.vio.VioSettings` (``vio``), or a preset name.
        sequence: the sequence the frames come from (its IMU samples, its kind of poses).
        matcher: the pipeline's matcher, for a source that tracks features (``vio``; default SIFT).
        stream: a :class:`~vio_depth.pipeline.FrameStream`'s inputs instead of a sequence: the
            ``imu`` and ``vio`` sources are then built when the first IMU samples arrive
            (:class:`~vio_depth.pipeline.feed.LazyImuPoses`).

    Raises:
        UnknownNameError (a ValueError): an unknown preset name (lists the valid ones).
        SettingsError: settings of no pose source.
        InputError: ``imu`` / ``vio`` on a sequence without IMU samples, or on a stream without
            an IMU calibration.
    """
    if isinstance(settings, str):
        settings = POSE_PRESETS[settings]
    match settings:
        case GroundTruthPoseSettings():
            kind = stream.pose_kind if stream is not None else "exact" if sequence is None else sequence.pose_kind
            return PoseStage(GroundTruthPoses(settings, kind))
        case ImuPoseSettings():
            if stream is None:
                return PoseStage(ImuPoseSource.for_sequence(sequence, settings))
            _require_calibration(stream, "imu")
            import_gtsam()  # now, not at the first frame
            return PoseStage(LazyImuPoses("imu", stream, lambda imu: ImuPoseSource(imu, stream, settings)))
        case VioSettings():
            matcher = create_matcher("sift") if matcher is None else matcher
            if stream is None:
                VioPoseSource.check_sequence(sequence)
                worker = ProcessWindow() if settings.backend.kind == "process" else None
                source = VioPoseSource(sequence.imu, matcher, settings, worker)
            else:
                _require_calibration(stream, "vio")
                import_gtsam()  # now, not at the first frame
                # the source waits for the first IMU samples; the window's worker, if any, starts
                # now and the stream is built once it answers: its interpreter takes 1-3 s to
                # import the pipeline, which would otherwise compete with the first frames
                worker = ProcessWindow() if settings.backend.kind == "process" else None
                if worker is not None:
                    worker.ping()
                source = LazyImuPoses("vio", stream, lambda imu: VioPoseSource(imu, matcher, settings, worker),
                                      matcher)
            return PoseStage(source, source, () if worker is None else (worker,))
        case _:
            raise SettingsError(f"no pose source for settings of type {type(settings).__name__}; valid: "
                                "GroundTruthPoseSettings, ImuPoseSettings, VioSettings "
                                f"(presets {', '.join(POSE_PRESETS)})")


def create_pose_source(settings: PoseSettings | str, sequence=None, matcher: Matcher | None = None) -> PoseSource:
    """The pose source for ``settings`` and ``sequence`` (:func:`build_pose_stage`'s source)."""
    return build_pose_stage(settings, sequence, matcher).source


def _require_calibration(stream: StreamInputs, name: str) -> None:
    if stream.imu_calibration is None:
        raise InputError(f"the {name} pose source needs imu_calibration (an ImuData with T_c_i and noise densities)")


def needs_features(settings: PipelineSettings) -> bool:
    """Whether a stage built from ``settings`` extracts features (two-view or landmark points, ``vio``)."""
    return _points_need_features(settings) or tracks_frames(settings.poses)


def _points_need_features(settings: PipelineSettings) -> bool:
    return settings.points.kind in (PointSourceKind.SFM, PointSourceKind.LANDMARKS)


def build_matcher(settings: PipelineSettings) -> Matcher | None:
    """The matcher of ``settings.matcher`` when a stage needs features (:func:`needs_features`), else None."""
    return create_matcher(settings.matcher) if needs_features(settings) else None


def build_points_stage(settings: PipelineSettings, pose_source: PoseSource, matcher: Matcher | None,
                       sequence=None) -> PointsStage | None:
    """The points stage of ``settings.points`` (None for the reference sources sampled from ground truth).

    ``landmarks`` takes the sequence's poses as priors under ``gt`` (their stated
    uncertainty), and any other source's relative poses with their covariance as motion
    factors; ``vio`` reads the odometry's own landmarks.

    Raises:
        SettingsError: ``vio`` with any pose source but ``vio``.
    """
    match settings.points.kind:
        case PointSourceKind.SFM:
            return TwoViewPoints(matcher, pose_source, settings.pairing, settings.triangulation,
                                 settings.min_matches, settings.consistency)
        case PointSourceKind.LANDMARKS if isinstance(pose_source, GroundTruthPoses):
            worker = ProcessWindow() if settings.landmarks_backend.kind == "process" else None
            return LandmarkPointsStage(
                matcher, settings.landmarks.resolved("mocap" if sequence is None else sequence.pose_kind),
                pose_source.uncertainty, settings.consistency, worker, settings.landmarks_backend)
        case PointSourceKind.LANDMARKS:
            if settings.landmarks_backend.kind != "inline":
                raise SettingsError(f"[landmarks_backend] kind = {settings.landmarks_backend.kind!r} runs the points "
                                    "window in a worker only with the sequence's poses (--poses gt); the "
                                    f"{pose_source.name!r} pose source's motion factors are built in this process: "
                                    "use kind = \"inline\" (the odometry's own window has [poses.backend])")
            # relative poses with their covariance (imu, vio) become the window's motion factors
            return SourceLandmarkPoints(matcher, pose_source, settings.landmarks)
        case PointSourceKind.VIO:
            if not isinstance(settings.poses, VioSettings):
                raise SettingsError("--points vio takes the odometry's own landmarks (--poses vio); the "
                                    f"{pose_source.name!r} pose source has none: use --points sfm or "
                                    "--points landmarks")
            return VioPoints(pose_source, matcher)
        case _:
            return None


def build_stages(settings: PipelineSettings, sequence=None, poses: PoseSource | PoseStage | None = None,
                 disparity_source: DisparitySource | None = None, matcher: Matcher | None = None) -> Stages:
    """Every stage of a pipeline from ``settings``; a stage given is used as it is.

    Args:
        settings: the pipeline's settings.
        sequence: the sequence the frames come from, when a source built here needs it.
        poses: a pose source (a tracker when it implements
            :class:`~vio_depth.poses.TrackingPoseSource`) or a :class:`PoseStage`; default:
            :func:`build_pose_stage` of ``settings.poses``.
        disparity_source: default: :func:`~vio_depth.disparity.create_disparity_source`.
        matcher: default: a tracker's own matcher, else :func:`build_matcher`.

    Raises:
        InputError: a tracking pose source with another matcher than the pipeline's, or a
            source that cannot be built for ``sequence``.
        SettingsError: see :func:`build_points_stage`.
    """
    stage = poses if isinstance(poses, PoseStage) or poses is None else PoseStage.of(poses)
    tracking = tracks_frames(settings.poses) if stage is None else stage.tracker is not None
    if matcher is None and tracking and stage is not None:
        matcher = stage.tracker.matcher
    if matcher is None and (_points_need_features(settings) or tracking):
        matcher = create_matcher(settings.matcher)
    if stage is None:
        stage = build_pose_stage(settings.poses, sequence, matcher)
    if stage.tracker is not None and stage.tracker.matcher is not matcher:
        raise InputError(f"the {stage.tracker.name} pose source must use the pipeline's matcher "
                         "(its features are extracted once, by the pipeline)")
    disparity = create_disparity_source(settings.disparity, sequence) if disparity_source is None else disparity_source
    points = build_points_stage(settings, stage.source, matcher, sequence)
    return Stages(matcher, stage, disparity, points)
