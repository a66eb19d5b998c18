"""Multi-view metric landmarks over a sliding keyframe window, refined with gtsam.

``tracks`` (feature tracks from pairwise matches), ``motion`` (the contract with whatever
gives the keyframes' motion: :class:`MotionFactorSource`, the default
:class:`PosePriorFactors`), ``window`` (gtsam sliding window: keyframes in, landmarks
out), ``graph`` (its factors and Levenberg-Marquardt), ``marginalisation``,
``covariance`` (the keyframe poses' joint covariance), ``query`` (a frame's metric
points), ``resection`` (pose refinement of a non-keyframe), ``estimator`` (per-frame
driver: matching, keyframe choice), ``snapshot`` (a read-only, picklable copy of the
window's state), ``backend`` (the window in a worker process), ``settings`` (pose-prior
presets per dataset kind, window settings, where the window runs), ``types``.
N-view triangulation lives in :mod:`triangulation.multiview`.

Typical use (one call per frame, features extracted once by the caller)::

    est = LandmarkEstimator(LandmarkSettings.for_poses("kinectfusion"), matcher)
    out = est.process(frame.index, frame.timestamp, frame.camera, frame.T_w_c, features)
    out.points.uv, out.points.depth, out.points.sigma_depth   # for the rescaler
"""

from .backend import ProcessWindow
from .covariance import PoseCovariances, prior_covariance
from .estimator import FrameLandmarks, LandmarkEstimator
from .graph import WindowGraph
from .marginalisation import marginalise_factors
from .motion import MotionFactors, MotionFactorSource, PosePriorFactors
from .resection import PoseRefinement, refine_pose
from .settings import (
    LANDMARK_SOLVERS,
    POSE_PRIOR_PRESETS,
    POINTS_WINDOW_BACKEND,
    WINDOW_BACKENDS,
    LandmarkSettings,
    PosePriorSettings,
    WindowBackendSettings,
    pose_prior_preset,
)
from .snapshot import WindowSnapshot
from .tracks import FrameMatches, Observations, TrackTable
from .types import KeyframeInput, LandmarkPoints, UpdateStatus, WindowUpdate, WorldLandmarks
from .window import LandmarkWindow

__all__ = [
    "LANDMARK_SOLVERS",
    "POSE_PRIOR_PRESETS",
    "POINTS_WINDOW_BACKEND",
    "WINDOW_BACKENDS",
    "FrameLandmarks",
    "FrameMatches",
    "KeyframeInput",
    "LandmarkEstimator",
    "LandmarkPoints",
    "LandmarkSettings",
    "LandmarkWindow",
    "MotionFactorSource",
    "MotionFactors",
    "Observations",
    "PoseCovariances",
    "PosePriorFactors",
    "PosePriorSettings",
    "PoseRefinement",
    "ProcessWindow",
    "TrackTable",
    "UpdateStatus",
    "WindowBackendSettings",
    "WindowGraph",
    "WindowSnapshot",
    "WindowUpdate",
    "WorldLandmarks",
    "marginalise_factors",
    "pose_prior_preset",
    "prior_covariance",
    "refine_pose",
]
