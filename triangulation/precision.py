"""How precise would a pair's points be? Predicted before matching, from the pose alone.

For a candidate pair the points stage knows the relative pose, its covariance and a
typical scene depth (the last frame's points), not yet the matches. A regular grid of
pixels of the current image, placed at that depth, stands in for them: each is projected
into the reference image and its first-order depth sigma computed exactly as
:func:`~triangulation.triangulate.triangulate_pair` would (pixel noise and the pose's
covariance). The lower quartile of their ``sigma_z / z`` -- the precision the better
quarter of the image reaches; with forward motion only the image borders have parallax --
is the pair's predicted precision: it grows as the baseline shrinks relative to the depth,
and is infinite for a pure rotation (no point has parallax), so pairing needs no fixed
rotation/translation threshold.
"""

from __future__ import annotations

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform

from .triangulate import ZERO_BASELINE_M, _depth_jacobian_pixels, _depth_jacobian_pose


def predicted_depth_error(camera_cur: Camera, camera_ref: Camera, T_ref_cur, covariance, depth_m: float,
                          pixel_sigma_px: float, grid: int = 7, quantile: float = 0.25) -> float:
    """Predicted relative depth sigma of a pair's points (module docstring).

    Args:
        camera_cur, camera_ref: the two cameras (ideal pixels are used).
        T_ref_cur: (4, 4) current-camera-to-reference-camera transform, metres.
        covariance: (6, 6) covariance of ``T_ref_cur`` (rotation rad, translation m; right
            perturbation), or None (exact).
        depth_m: typical depth of the scene in the current camera, metres (> 0).
        pixel_sigma_px: 1-sigma keypoint noise, pixels.
        grid: the grid has ``grid x grid`` pixels over the central 80 % of the image.
        quantile: which quantile of the grid points' relative sigma is returned.

    Returns:
        unit-free (0.05 = 5 %), over the grid points seen by both cameras; ``inf`` when the
        baseline is zero or fewer than a quarter of the grid points are in front of both
        cameras and inside the reference image.
    """
    T = check_transform("T_ref_cur", T_ref_cur)
    cov = None if covariance is None else check_array("covariance", covariance, (6, 6), finite=True)
    if not (np.isfinite(depth_m) and depth_m > 0):
        return float("inf")
    R, t = T[:3, :3], T[:3, 3]
    if np.linalg.norm(t) < ZERO_BASELINE_M:
        return float("inf")
    u = np.linspace(0.1, 0.9, grid) * camera_cur.width
    v = np.linspace(0.1, 0.9, grid) * camera_cur.height
    uv = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
    K_cur_inv, K_ref_inv = np.linalg.inv(camera_cur.K), np.linalg.inv(camera_ref.K)
    rays = np.column_stack([uv, np.ones(len(uv))]) @ K_cur_inv.T
    points = rays * depth_m
    in_ref = points @ R.T + t
    front = in_ref[:, 2] > 1e-6
    proj = in_ref[front] @ camera_ref.K.T
    uv_ref = proj[:, :2] / proj[:, 2:]
    inside = (uv_ref[:, 0] >= 0) & (uv_ref[:, 0] < camera_ref.width) & (uv_ref[:, 1] >= 0) & (
        uv_ref[:, 1] < camera_ref.height)
    if inside.sum() < max(1, len(uv) // 4):
        return float("inf")
    ic, ir = uv[front][inside], uv_ref[inside]
    with np.errstate(invalid="ignore", divide="ignore"):
        var = pixel_sigma_px**2 * np.sum(_depth_jacobian_pixels(ic, ir, K_cur_inv, K_ref_inv, R, t) ** 2, axis=1)
        if cov is not None:
            J = _depth_jacobian_pose(ic, ir, K_cur_inv, K_ref_inv, R, t)
            var = var + np.einsum("ni,ij,nj->n", J, cov, J)
        rel = np.sqrt(np.maximum(var, 0.0)) / depth_m
    rel = np.where(np.isfinite(rel), rel, np.inf)
    return float(np.quantile(rel, quantile))


def depth_pose_jacobian(uv_cur, depth, camera_cur: Camera, camera_ref: Camera, T_ref_cur) -> np.ndarray:
    """(N, 6) metres per (rad, m): how the two-view depth of points seen at ``uv_cur`` at
    ``depth`` would move with an error of the relative pose ``T_ref_cur`` (right
    perturbation, rotation first), as in :func:`~triangulation.triangulate.triangulate_pair`.

    For points whose depth came from elsewhere (a multi-view window), it states what a
    pose error relative to ``camera_ref`` does to them: every point moves together, so the
    rows are the shared part of their uncertainty.

    Args:
        uv_cur: (N, 2) raw pixels in the current image.
        depth: (N,) metres, z in the current camera (> 0).
        camera_cur, camera_ref: the two cameras.
        T_ref_cur: (4, 4) current-camera-to-reference-camera transform, metres.

    Returns:
        (N, 6); rows of points without parallax (zero baseline, behind the reference
        camera) are zeros.
    """
    uv = check_array("uv_cur", uv_cur, (None, 2), finite=True).astype(np.float64)
    z = check_array("depth", depth, (len(uv),), finite=True).astype(np.float64)
    T = check_transform("T_ref_cur", T_ref_cur)
    R, t = T[:3, :3], T[:3, 3]
    out = np.zeros((len(uv), 6))
    if len(uv) == 0 or np.linalg.norm(t) < ZERO_BASELINE_M:
        return out
    ic = camera_cur.undistort_points(uv)
    K_cur_inv, K_ref_inv = np.linalg.inv(camera_cur.K), np.linalg.inv(camera_ref.K)
    points = (np.column_stack([ic, np.ones(len(ic))]) @ K_cur_inv.T) * z[:, None]
    in_ref = points @ R.T + t
    front = (in_ref[:, 2] > 1e-6) & (z > 0)
    if not front.any():
        return out
    proj = in_ref[front] @ camera_ref.K.T
    ir = proj[:, :2] / proj[:, 2:]
    with np.errstate(invalid="ignore", divide="ignore"):
        J = _depth_jacobian_pose(ic[front], ir, K_cur_inv, K_ref_inv, R, t)
    out[front] = np.where(np.isfinite(J), J, 0.0)
    return out
