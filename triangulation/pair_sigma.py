"""The predicted depth precision of two-view matches in closed form: :func:`two_view_relative_sigma`.

A keyframe decision asks how precisely the matches between the newest keyframe and the current
frame would fix their depth (the two-view parallax test of
:class:`~vio_depth.landmarks.LandmarkEstimator`). :func:`~.multiview.triangulate_tracks` answers
that for any number of views with Gauss-Newton, outlier rounds and statuses: 6-9 ms for 300
matches, most of it a fixed cost of its iterations, on a third of the frames of a camera-rate
stream. For two views the point is the midpoint of the two rays, and its first-order covariance
and the depth sigma follow with the same terms as there (pixel noise, the current view's pose
covariance and their cross term), row by row.
"""

from __future__ import annotations

import numpy as np

from vio_core import Camera
from vio_core.checks import check_array, check_transform

from .batched import inv2, inv3
from .jacobians import depth_variance, image_pose_jacobian, normal_terms, point_jacobian, sandwich2

#: below this ray angle (degrees) a pair has no parallax (as the multi-view triangulation's test)
_MIN_ANGLE_DEG = 1e-3


def two_view_relative_sigma(uv_a: np.ndarray, uv_b: np.ndarray, camera_a: Camera, camera_b: Camera,
                            T_w_a: np.ndarray, T_w_b: np.ndarray, covariance_b: np.ndarray,
                            pixel_sigma_px: float = 1.0, max_residual_sigmas: float = 3.0) -> np.ndarray:
    """``sigma_z / z`` of each match's depth in view ``b``, NaN where it does not triangulate.

    Args:
        uv_a, uv_b: (N, 2) raw (distorted) pixels of the N matches in views a and b.
        camera_a, camera_b: the views' cameras.
        T_w_a, T_w_b: (4, 4) camera-to-world poses, metres; a's is taken as exact.
        covariance_b: (6, 6) covariance of b's pose (right perturbation ``T_w_b * Exp(xi)``,
            rotation rad first, then metres).
        pixel_sigma_px: 1-sigma keypoint noise, ideal pixels.
        max_residual_sigmas: a match whose whitened reprojection error at the midpoint exceeds
            this in either view is left out (NaN), as an outlier of the multi-view triangulation.

    Returns:
        (N,) the first-order relative depth sigma in view b (the variance of the point from both
        views' pixel noise and b's pose, plus b's pose directly and their cross term); NaN for
        matches behind either camera, without parallax or beyond the residual gate.
    """
    uv_a = check_array("uv_a", uv_a, (None, 2), finite=True).astype(np.float64)
    n = len(uv_a)
    uv_b = check_array("uv_b", uv_b, (n, 2), finite=True).astype(np.float64)
    T_w_a, T_w_b = check_transform("T_w_a", T_w_a), check_transform("T_w_b", T_w_b)
    C_b = check_array("covariance_b", covariance_b, (6, 6), finite=True)
    if n == 0:
        return np.zeros(0)
    ideal_a, ideal_b = camera_a.undistort_points(uv_a), camera_b.undistort_points(uv_b)
    R_wa, R_wb = T_w_a[:3, :3], T_w_b[:3, :3]
    c_a, c_b = T_w_a[:3, 3], T_w_b[:3, 3]
    d_a = np.column_stack([(ideal_a[:, 0] - camera_a.cx) / camera_a.fx, (ideal_a[:, 1] - camera_a.cy) / camera_a.fy,
                           np.ones(n)]) @ R_wa.T
    d_b = np.column_stack([(ideal_b[:, 0] - camera_b.cx) / camera_b.fx, (ideal_b[:, 1] - camera_b.cy) / camera_b.fy,
                           np.ones(n)]) @ R_wb.T
    d_a /= np.linalg.norm(d_a, axis=1, keepdims=True)
    d_b /= np.linalg.norm(d_b, axis=1, keepdims=True)
    # the midpoint of the closest points of the rays c_a + s d_a and c_b + t d_b
    base = c_b - c_a
    k = np.einsum("ij,ij->i", d_a, d_b)  # cosine of the ray angle
    ba, bb = d_a @ base, d_b @ base
    den = 1.0 - k * k
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (ba - k * bb) / den
        t = (k * ba - bb) / den
    X = 0.5 * (c_a + s[:, None] * d_a + c_b + t[:, None] * d_b)
    R_aw, R_bw = R_wa.T, R_wb.T
    p_a, p_b = (X - c_a) @ R_aw.T, (X - c_b) @ R_bw.T  # (N, 3) camera points
    ok = (np.degrees(np.arccos(np.clip(k, -1.0, 1.0))) >= _MIN_ANGLE_DEG) & (p_a[:, 2] > 0) & (p_b[:, 2] > 0)
    p_a[~ok] = p_b[~ok] = (0.0, 0.0, 1.0)  # placeholders: the NaN rows are dropped at the end

    # whitening: pixel noise, plus b's pose uncertainty moving its image
    s2 = float(pixel_sigma_px) ** 2
    S_a = np.zeros((n, 2, 2))
    S_a[:, 0, 0] = S_a[:, 1, 1] = s2
    J_pose = image_pose_jacobian(p_b, camera_b.fx, camera_b.fy)  # (N, 2, 6)
    S_b = sandwich2(J_pose, np.broadcast_to(C_b, (n, 6, 6)))
    S_b[:, 0, 0] += s2
    S_b[:, 1, 1] += s2
    Si_a, Si_b = inv2(S_a), inv2(S_b)
    r_a = ideal_a - _project(p_a, camera_a)
    r_b = ideal_b - _project(p_b, camera_b)
    gate = max_residual_sigmas ** 2
    ok &= (np.einsum("ni,nij,nj->n", r_a, Si_a, r_a) <= gate) & (np.einsum("ni,nij,nj->n", r_b, Si_b, r_b) <= gate)

    H_a, _, _ = normal_terms(point_jacobian(p_a, camera_a.fx, camera_a.fy, np.broadcast_to(R_aw, (n, 3, 3))), Si_a)
    H_b, _, JtS_b = normal_terms(point_jacobian(p_b, camera_b.fx, camera_b.fy, np.broadcast_to(R_bw, (n, 3, 3))), Si_b)
    P = inv3(H_a + H_b)[0]  # (N, 3, 3) world covariance of the point
    a = np.broadcast_to(R_bw[2], (n, 3))  # dz_b / dX
    var = depth_variance(a, P @ R_bw[2], p_b, np.broadcast_to(C_b, (n, 6, 6)), JtS_b, J_pose)
    rel = np.sqrt(np.maximum(var, 0.0)) / p_b[:, 2]
    return np.where(ok & np.isfinite(rel), rel, np.nan)


def _project(p_c: np.ndarray, camera: Camera) -> np.ndarray:
    """(N, 2) ideal pixels of camera points ``p_c: (N, 3)`` metres (z > 0)."""
    return np.column_stack([camera.fx * p_c[:, 0] / p_c[:, 2] + camera.cx,
                            camera.fy * p_c[:, 1] / p_c[:, 2] + camera.cy])
