"""Pipeline stage: one frame in, metric points, a fit and a metric depth map out.

=================  ============================================================================
module             job
=================  ============================================================================
``status``         :class:`FrameStatus`, :class:`PairStatus`, :func:`decide_frame_status`
``result``         :class:`FrameResult`, :class:`PointsOutcome`, :class:`PairAttempt`, :class:`PreparedFrame`
``points``         :class:`TwoViewPoints`: pairing with keyframes, triangulation, merging
``landmark_points`` :class:`LandmarkPointsStage`: multi-view landmarks over a keyframe window
``source_landmarks`` :class:`SourceLandmarkPoints`: the same with a relative pose source's factors (imu, vio)
``vio_points``     :class:`VioPoints`: the odometry's own landmarks (``--points vio``)
``settings``       :class:`PipelineSettings` (one settings object per stage, presets, TOML)
``pipeline``       :class:`Pipeline` (``process(frame)`` = ``process_prepared(prepare(frame))``)
``stream``         :class:`FrameStream` (``push(image, disparity, ...)`` from arrays)
=================  ============================================================================
"""

from .landmark_points import LandmarkPointsStage
from .pipeline import Pipeline
from .points import TwoViewPoints, most_certain_per_keypoint
from .result import PIPELINE_STAGES, FrameResult, LandmarkInfo, PairAttempt, PointsOutcome, PreparedFrame
from .settings import PRESET_FAMILIES, PipelineSettings
from .source_landmarks import SourceLandmarkPoints
from .status import FrameStatus, PairStatus, decide_frame_status
from .stream import FrameStream
from .vio_points import VioPoints

__all__ = [
    "PIPELINE_STAGES",
    "PRESET_FAMILIES",
    "FrameResult",
    "FrameStatus",
    "FrameStream",
    "LandmarkInfo",
    "LandmarkPointsStage",
    "PairAttempt",
    "PairStatus",
    "Pipeline",
    "PipelineSettings",
    "PointsOutcome",
    "PreparedFrame",
    "SourceLandmarkPoints",
    "TwoViewPoints",
    "VioPoints",
    "decide_frame_status",
    "most_certain_per_keypoint",
]
