"""Two-view triangulation of matched keypoints with a known metric relative pose."""

from .triangulate import (
    PointStatus,
    TriangulatedPoints,
    TriangulationSettings,
    correct_matches,
    fundamental_from_pose,
    sampson_distance,
    triangulate_pair,
)

__all__ = [
    "PointStatus",
    "TriangulatedPoints",
    "TriangulationSettings",
    "correct_matches",
    "fundamental_from_pose",
    "sampson_distance",
    "triangulate_pair",
]
