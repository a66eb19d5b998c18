"""Multi-view metric landmarks over a sliding keyframe window, refined with gtsam.

``tracks`` (feature tracks from pairwise matches), ``window`` (gtsam sliding window with
pose priors, projection factors and marginalisation; per-frame query), ``resection``
(pose refinement of a non-keyframe), ``estimator`` (per-frame driver), ``settings``.
"""

from .estimator import FrameLandmarks, LandmarkEstimator
from .resection import PoseRefinement, refine_pose
from .settings import POSE_PRIOR_PRESETS, LandmarkSettings, PosePriorSettings, pose_prior_preset
from .tracks import FrameMatches, Observations, TrackTable
from .window import KeyframeInput, LandmarkPoints, LandmarkWindow, MotionFactorSource, WindowUpdate

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
