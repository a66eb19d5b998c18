"""Evaluation against ground truth: dense depth metrics, the oracle fit, point accuracy,
reference point sources sampled from ground truth (``--points lidar:N`` / ``random:N``),
camera trajectories (TUM files, ATE, RPE) and the IMU pose source's propagation error and NEES.

=====================  ======================================================================
module                 job
=====================  ======================================================================
``metrics``            :func:`compute_metrics` (delta1, AbsRel, RMSE), :func:`oracle_fit`
``frame``              :func:`evaluate_frame`: one frame's result against its ground truth
``masks``              :class:`EvalMask`: depth caps and the KITTI Garg / Eigen crops
``point_accuracy``     :func:`point_depth_errors` of metric points against ground-truth depth
``reference_points``   the LiDAR / random samplers of ``--points lidar:N`` / ``random:N``
``trajectory``         :class:`CameraTrajectory`, TUM files, ATE (SE(3), no scale) and RPE (evo)
``imu_propagation``    :func:`evaluate_propagation`: ``--poses imu`` errors and NEES against ground truth
``consistency``        NEES and the bounds a consistent estimator meets (mean, median, fraction)
``perturb``            seeded perturbations of the robustness studies (:data:`STUDIES`)
=====================  ======================================================================
"""

from .consistency import mean_nees_bounds, median_nees_bounds, nees, within_fraction_bound
from .frame import FrameEvaluation, aggregate_point_accuracy, evaluate_frame
from .imu_propagation import PropagationErrors, evaluate_propagation, ground_truth_frames
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
from .reference_points import beam_rows, lidar_beams, random_samples
from .trajectory import (
    AteResult,
    CameraTrajectory,
    ErrorStats,
    RpeResult,
    absolute_trajectory_error,
    associate,
    pairs_by_path,
    read_trajectory_tum,
    relative_pose_error,
    umeyama_alignment,
    write_trajectory_tum,
)

__all__ = [
    "CROPS",
    "STUDIES",
    "AteResult",
    "CameraTrajectory",
    "DepthMetrics",
    "ErrorStats",
    "EvalMask",
    "FrameEvaluation",
    "ImuNoiseBoost",
    "OutlierDraw",
    "PerturbedSequence",
    "PointAccuracy",
    "PoseNoise",
    "PropagationErrors",
    "RpeResult",
    "SparsePoints",
    "Study",
    "absolute_trajectory_error",
    "add_outliers",
    "aggregate_point_accuracy",
    "associate",
    "average_metrics",
    "beam_rows",
    "compute_metrics",
    "crop_bounds",
    "depth_noise",
    "depth_reprojection_errors",
    "evaluate_frame",
    "evaluate_propagation",
    "ground_truth_frames",
    "lidar_beams",
    "lidar_points",
    "mean_nees_bounds",
    "median_nees_bounds",
    "nees",
    "oracle_fit",
    "pairs_by_path",
    "perturb_imu",
    "perturb_pose",
    "point_depth_errors",
    "random_samples",
    "read_trajectory_tum",
    "relative_pose_error",
    "shift_pixels",
    "umeyama_alignment",
    "within_fraction_bound",
    "write_trajectory_tum",
]
