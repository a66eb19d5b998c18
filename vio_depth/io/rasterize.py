"""Depth images from 3-D points: rasterising point clouds and re-projecting depth between cameras."""

from __future__ import annotations

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform


def rasterize_depth(points_c, camera: Camera) -> np.ndarray:
    """Sparse depth image of 3-D points, keeping the nearest point per pixel.

    Args:
        points_c: (N, 3) metres in the camera frame of ``camera`` (z forward).
        camera: pinhole camera (undistorted pixel grid).

    Returns:
        (H, W) float32 metres, 0 where no point falls.
    """
    p = check_array("points_c", points_c, (None, 3))
    depth = np.zeros((camera.height, camera.width), np.float32)
    p = p[np.isfinite(p).all(axis=1) & (p[:, 2] > 0)]
    if len(p) == 0:
        return depth
    uv, z = camera.project(p)
    uv = np.round(uv)
    # bounds tested on the floats: a point just in front of the camera projects to +-inf
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    col, row, z = uv[inside, 0].astype(np.int64), uv[inside, 1].astype(np.int64), z[inside]
    order = np.argsort(-z, kind="stable")  # far first: nearer points overwrite them
    depth[row[order], col[order]] = z[order]
    return depth


def register_depth(depth, depth_camera: Camera, colour_camera: Camera, T_colour_depth) -> np.ndarray:
    """Re-project a depth image into another camera (nearest surface per pixel).

    Args:
        depth: (H_d, W_d) metres in ``depth_camera``'s pixel grid, 0 = invalid.
        depth_camera: camera of ``depth``.
        colour_camera: target camera.
        T_colour_depth: (4, 4) depth-camera-to-target-camera transform, metres.

    Returns:
        (H_c, W_c) float32 metres in the target camera (z), 0 = no depth.
    """
    d = check_array("depth", depth, (depth_camera.height, depth_camera.width))
    T = check_transform("T_colour_depth", T_colour_depth)
    v, u = np.nonzero(np.isfinite(d) & (d > 0))
    if len(u) == 0:
        return np.zeros((colour_camera.height, colour_camera.width), np.float32)
    p_d = depth_camera.backproject(np.stack([u, v], axis=1).astype(np.float64), d[v, u].astype(np.float64))
    return rasterize_depth(p_d @ T[:3, :3].T + T[:3, 3], colour_camera)
