"""Evaluation against ground truth: dense depth metrics, the oracle fit, point accuracy,
and reference point sources sampled from ground truth (``--points lidar:N`` / ``random:N``).

=====================  ======================================================================
module                 job
=====================  ======================================================================
``metrics``            :func:`compute_metrics` (delta1, AbsRel, RMSE), :func:`oracle_fit`
``frame``              :func:`evaluate_frame`: one frame's result against its ground truth
``masks``              :class:`EvalMask`: depth caps and the KITTI Garg / Eigen crops
``point_accuracy``     :func:`point_depth_errors` of metric points against ground-truth depth
``reference_points``   :class:`PointSourceSpec` and the LiDAR / random samplers
``perturb``            seeded perturbations of the robustness studies (:data:`STUDIES`)
``tasks``              :func:`run_tasks`: tasks sequentially, on a process pool or on Ray, cached
=====================  ======================================================================
"""

from .frame import FrameEvaluation, aggregate_point_accuracy, evaluate_frame
from .masks import CROPS, EvalMask, crop_bounds
from .metrics import DepthMetrics, average_metrics, compute_metrics, depth_reprojection_errors, oracle_fit
from .perturb import (
    STUDIES,
    ImuNoiseBoost,
    OutlierDraw,
    PerturbedSequence,
    PoseNoise,
    SparsePoints,
    Study,
    add_outliers,
    depth_noise,
    lidar_points,
    perturb_imu,
    perturb_pose,
    shift_pixels,
)
from .point_accuracy import PointAccuracy, point_depth_errors
from .reference_points import (
    POINT_SPEC_FORMS,
    PointSourceKind,
    PointSourceSpec,
    lidar_beams,
    parse_points_spec,
    random_samples,
)
from .tasks import EXECUTORS, ExecutorSettings, Task, TaskCache, TaskError, execute_task, package_version, run_tasks

__all__ = [
    "CROPS",
    "EvalMask",
    "crop_bounds",
    "DepthMetrics",
    "EXECUTORS",
    "ExecutorSettings",
    "FrameEvaluation",
    "ImuNoiseBoost",
    "OutlierDraw",
    "POINT_SPEC_FORMS",
    "PerturbedSequence",
    "PointAccuracy",
    "PointSourceKind",
    "PointSourceSpec",
    "PoseNoise",
    "STUDIES",
    "SparsePoints",
    "Study",
    "Task",
    "TaskCache",
    "TaskError",
    "add_outliers",
    "aggregate_point_accuracy",
    "average_metrics",
    "compute_metrics",
    "depth_noise",
    "depth_reprojection_errors",
    "evaluate_frame",
    "execute_task",
    "lidar_beams",
    "lidar_points",
    "oracle_fit",
    "package_version",
    "parse_points_spec",
    "perturb_imu",
    "perturb_pose",
    "point_depth_errors",
    "random_samples",
    "run_tasks",
    "shift_pixels",
]
