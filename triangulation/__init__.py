"""Triangulation with known metric poses: two views (``triangulate``) on their epipolar
geometry (``epipolar``), N-view tracks with pose uncertainty (``multiview``, its projection
Jacobians in ``jacobians``, its batched small algebra in ``batched``), whether the
images agree with a stated pose (``consistency``) and how precise a pair's points would be
(``precision``; two views' matches in closed form: ``pair_sigma``).

A leaf layer: it imports only :mod:`vio_core` (and numpy, scipy).
"""

from .consistency import ConsistencySettings, PoseConsistency, PoseInflation, pose_consistency
from .epipolar import correct_matches, fundamental_from_pose, sampson_distance
from .multiview import (
    MultiviewPoints,
    MultiviewSettings,
    TrackStatus,
    depth_in_view,
    triangulate_tracks,
)
from .pair_sigma import two_view_relative_sigma
from .precision import depth_pose_jacobian, predicted_depth_error
from .triangulate import (
    TRIANGULATION_PRESETS,
    PointStatus,
    TriangulatedPoints,
    TriangulationSettings,
    triangulate_pair,
)

__all__ = [
    "TRIANGULATION_PRESETS",
    "ConsistencySettings",
    "MultiviewPoints",
    "MultiviewSettings",
    "PoseConsistency",
    "PoseInflation",
    "TrackStatus",
    "depth_in_view",
    "depth_pose_jacobian",
    "pose_consistency",
    "predicted_depth_error",
    "triangulate_tracks",
    "two_view_relative_sigma",
    "PointStatus",
    "TriangulatedPoints",
    "TriangulationSettings",
    "correct_matches",
    "fundamental_from_pose",
    "sampson_distance",
    "triangulate_pair",
]
