"""Evaluation against ground truth: dense depth metrics, the oracle fit, point accuracy,
and reference point sources sampled from ground truth (``--points lidar:N`` / ``random:N``).

=====================  ======================================================================
module                 job
=====================  ======================================================================
``metrics``            :func:`compute_metrics` (delta1, AbsRel, RMSE), :func:`oracle_fit`
``frame``              :func:`evaluate_frame`: one frame's result against its ground truth
``point_accuracy``     :func:`point_depth_errors` of metric points against ground-truth depth
``reference_points``   :class:`PointSourceSpec` and the LiDAR / random samplers
=====================  ======================================================================
"""

from .frame import FrameEvaluation, aggregate_point_accuracy, evaluate_frame
from .metrics import DepthMetrics, average_metrics, compute_metrics, depth_reprojection_errors, oracle_fit
from .point_accuracy import PointAccuracy, point_depth_errors
from .reference_points import (
    POINT_SPEC_FORMS,
    PointSourceKind,
    PointSourceSpec,
    lidar_beams,
    parse_points_spec,
    random_samples,
)

__all__ = [
    "POINT_SPEC_FORMS",
    "DepthMetrics",
    "FrameEvaluation",
    "PointAccuracy",
    "PointSourceKind",
    "PointSourceSpec",
    "aggregate_point_accuracy",
    "average_metrics",
    "compute_metrics",
    "depth_reprojection_errors",
    "evaluate_frame",
    "lidar_beams",
    "oracle_fit",
    "parse_points_spec",
    "point_depth_errors",
    "random_samples",
]
