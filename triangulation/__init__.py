"""Triangulation with known metric poses: two views (``triangulate``) and N-view tracks
with pose uncertainty (``multiview``).

A leaf layer: it imports only :mod:`vio_core` (and numpy, scipy).
"""

from .multiview import (
    MultiviewPoints,
    MultiviewSettings,
    TrackStatus,
    depth_in_view,
    triangulate_tracks,
)
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
    "MultiviewPoints",
    "MultiviewSettings",
    "TrackStatus",
    "depth_in_view",
    "triangulate_tracks",
    "PointStatus",
    "TriangulatedPoints",
    "TriangulationSettings",
    "correct_matches",
    "fundamental_from_pose",
    "sampson_distance",
    "triangulate_pair",
]
