"""Multi-view metric landmarks over a sliding keyframe window, refined with gtsam.

``tracks`` (feature tracks from pairwise matches), ``window`` (gtsam sliding window with
pose priors, projection factors and marginalisation; per-frame query), ``resection``
(pose refinement of a non-keyframe), ``estimator`` (per-frame driver: matching, keyframe
choice), ``settings`` (pose-prior presets per dataset kind, window settings), ``types``.
N-view triangulation lives in :mod:`triangulation.multiview`.

Typical use (one call per frame, features extracted once by the caller)::

    est = LandmarkEstimator(LandmarkSettings.for_poses("kinectfusion"), matcher)
    out = est.process(frame.index, frame.timestamp, frame.camera, frame.T_w_c, features)
    out.points.uv, out.points.depth, out.points.sigma_depth   # for the rescaler
"""

from .estimator import FrameLandmarks, LandmarkEstimator
from .resection import PoseRefinement, refine_pose
from .settings import POSE_PRIOR_PRESETS, LandmarkSettings, PosePriorSettings, pose_prior_preset
from .tracks import FrameMatches, Observations, TrackTable
from .types import KeyframeInput, LandmarkPoints, MotionFactorSource, WindowUpdate
from .window import LandmarkWindow

__all__ = [
    "POSE_PRIOR_PRESETS",
    "FrameLandmarks",
    "FrameMatches",
    "KeyframeInput",
    "LandmarkEstimator",
    "LandmarkPoints",
    "LandmarkSettings",
    "LandmarkWindow",
    "MotionFactorSource",
    "Observations",
    "PosePriorSettings",
    "PoseRefinement",
    "TrackTable",
    "WindowUpdate",
    "pose_prior_preset",
    "refine_pose",
]
