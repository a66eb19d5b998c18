"""Pipeline stage: one frame in, metric points, a fit and a metric depth map out.

=================  ============================================================================
module             job
=================  ============================================================================
``status``         :class:`FrameStatus`, :class:`PairStatus`, :func:`decide_frame_status`
``result``         :class:`FrameResult`, :class:`PointsOutcome`, :class:`PairAttempt`, :class:`PreparedFrame`
``points``         :class:`TwoViewPoints`: pairing with keyframes, triangulation, merging
``landmark_points`` :class:`LandmarkPointsStage`: multi-view landmarks over a keyframe window
``point_source``   :class:`PointSourceSpec` (``--points``: sfm, landmarks, lidar:N, random:N)
``settings``       :class:`PipelineSettings` (one settings object per stage, presets, TOML),
                   :data:`POSE_PRESETS`
``build``          :func:`build_stages`: matcher, pose source, disparity source, points stage from
                   the settings, by explicit calls (:func:`build_pose_stage`, :func:`create_pose_source`)
``feed``           a stream's frames and IMU samples, its lazily built ``imu`` / ``vio`` source
``tracking``       a tracking matcher's (KLT) frames in order, with the rotation predicted
``source_landmarks`` :class:`SourceLandmarkPoints`: the same with a relative pose source's factors (imu, vio)
``vio_points``     :class:`VioPoints`: the odometry's own landmarks (``--points vio``)
``pipeline``       :class:`Pipeline` (``process(frame)`` = ``process_prepared(prepare(frame))``)
``stream``         :class:`FrameStream` (``push(image, disparity, ...)`` from arrays)
=================  ============================================================================
"""

from .build import (
    PoseStage,
    Stages,
    build_matcher,
    build_points_stage,
    build_pose_stage,
    build_stages,
    create_pose_source,
)
from .landmark_points import LandmarkPointsStage
from .pipeline import Pipeline
from .point_source import POINT_SPEC_FORMS, PointSourceKind, PointSourceSpec, parse_points_spec
from .points import TwoViewPoints, most_certain_per_keypoint
from .result import PIPELINE_STAGES, FrameResult, LandmarkInfo, PairAttempt, PointsOutcome, PreparedFrame
from .settings import (POSE_PRESETS, PRESET_FAMILIES, TRACKER_DEFAULTS, VIO_CAMERA_RATE, PipelineSettings,
                       PoseSettings, chooses_preset, default_matcher_preset, default_points_spec,
                       with_tracker_defaults)
from .source_landmarks import SourceLandmarkPoints
from .status import FrameStatus, PairStatus, decide_frame_status
from .stream import FrameStream
from .tracking import TrackedExtraction
from .vio_points import VioPoints

__all__ = [
    "PIPELINE_STAGES",
    "POINT_SPEC_FORMS",
    "POSE_PRESETS",
    "PRESET_FAMILIES",
    "TRACKER_DEFAULTS",
    "VIO_CAMERA_RATE",
    "FrameResult",
    "FrameStatus",
    "FrameStream",
    "LandmarkInfo",
    "LandmarkPointsStage",
    "PairAttempt",
    "PairStatus",
    "Pipeline",
    "PipelineSettings",
    "chooses_preset",
    "default_matcher_preset",
    "default_points_spec",
    "with_tracker_defaults",
    "PointSourceKind",
    "PointSourceSpec",
    "PointsOutcome",
    "PoseSettings",
    "PoseStage",
    "PreparedFrame",
    "SourceLandmarkPoints",
    "Stages",
    "TrackedExtraction",
    "TwoViewPoints",
    "build_matcher",
    "build_points_stage",
    "build_pose_stage",
    "build_stages",
    "create_pose_source",
    "VioPoints",
    "decide_frame_status",
    "most_certain_per_keypoint",
    "parse_points_spec",
]
