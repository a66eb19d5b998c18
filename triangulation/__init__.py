"""Two-view triangulation of matched keypoints with a known metric relative pose.

A leaf layer: it imports only :mod:`vio_core` (and numpy, scipy).
"""

from .triangulate import (
    TRIANGULATION_PRESETS,
    PointStatus,
    TriangulatedPoints,
    TriangulationSettings,
    correct_matches,
    fundamental_from_pose,
    sampson_distance,
    triangulate_pair,
)

__all__ = [
    "TRIANGULATION_PRESETS",
    "PointStatus",
    "TriangulatedPoints",
    "TriangulationSettings",
    "correct_matches",
    "fundamental_from_pose",
    "sampson_distance",
    "triangulate_pair",
]
