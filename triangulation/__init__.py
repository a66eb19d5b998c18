"""Triangulation with known metric poses: two views (``triangulate``) and N-view tracks
with pose uncertainty (``multiview``)."""

from .multiview import (
    MultiviewPoints,
    MultiviewSettings,
    TrackStatus,
    depth_in_view,
    triangulate_tracks,
)
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
