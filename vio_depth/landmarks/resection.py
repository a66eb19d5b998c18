"""Refinement of one frame's pose against known landmarks, with a pose prior (numpy).

Minimises, over ``T_w_c = T_prior * Exp(delta)``::

    sum_i rho(|r_i|_{S_i}) + delta^T Sigma_prior^-1 delta

where ``r_i`` is landmark i's reprojection residual in ideal pixels, whitened by
``S_i = sigma_px^2 I + J_X,i Sigma_X,i J_X,i^T`` (pixel noise plus the landmark's own
uncertainty projected into the image) and ``rho`` is Huber's loss (iteratively
reweighted). The prior keeps the metric scale and the directions the landmarks do not
constrain (few or distant landmarks); the landmarks correct the pose where they do.
Six unknowns: a dense 6x6 Gauss-Newton, vectorised over the landmarks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from triangulation.batched import inv2, quad2
from triangulation.jacobians import image_pose_jacobian, point_jacobian, sandwich2
from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform


@dataclass(frozen=True)
class PoseRefinement:
    """Result of :func:`refine_pose`.

    Attributes:
        T_w_c: (4, 4) refined camera-to-world pose, metres.
        covariance: (6, 6) covariance of ``T_w_c * Exp(xi)`` (rotation rad, translation m).
        inlier: (N,) bool, landmarks in front of the camera with a finite residual.
        whitened_residual: (N,) residual of each landmark in its own sigmas.
        residual_px: (N,) ideal pixels.
    """

    T_w_c: np.ndarray
    covariance: np.ndarray
    inlier: np.ndarray
    whitened_residual: np.ndarray
    residual_px: np.ndarray


def _exp(xi: np.ndarray) -> np.ndarray:
    """(4, 4) ``Exp(xi)``, first order in the coupling (exact rotation, translation as given)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(xi[:3]).as_matrix()
    T[:3, 3] = xi[3:]
    return T


def _normal_equations(J: np.ndarray, S_inv: np.ndarray, w: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(sum_n w_n J_n^T S_n^-1 J_n, sum_n w_n J_n^T S_n^-1 r_n)``: (6, 6) and (6,), from (N, 2, 6)
    Jacobians, (N, 2, 2) inverse covariances, (N,) weights and (N, 2) residuals, as two matrix
    products over all landmarks' rows."""
    s00, s01, s11 = (w * S_inv[:, 0, 0])[:, None], (w * S_inv[:, 0, 1])[:, None], (w * S_inv[:, 1, 1])[:, None]
    WJ = np.empty(J.shape)  # (N, 2, 6): w_n S_n^-1 J_n (S symmetric), row by row
    WJ[:, 0] = s00 * J[:, 0] + s01 * J[:, 1]
    WJ[:, 1] = s01 * J[:, 0] + s11 * J[:, 1]
    WJ = WJ.reshape(-1, 6)
    return WJ.T @ J.reshape(-1, 6), WJ.T @ r.reshape(-1)


def refine_pose(points_w, point_covariance, uv, camera: Camera, T_w_c_prior, prior_covariance,
                pixel_sigma_px: float = 1.0, huber_sigmas: float = 2.0, iterations: int = 5) -> PoseRefinement:
    """Refine a frame's pose against landmarks it observes (see the module docstring).

    Args:
        points_w: (N, 3) metres, landmark positions.
        point_covariance: (N, 3, 3) square metres (NaN entries count as zero).
        uv: (N, 2) raw pixels of the frame's observations of them.
        camera: the frame's camera (distortion handled by undistorting ``uv``).
        T_w_c_prior: (4, 4) prior camera-to-world pose, metres.
        prior_covariance: (6, 6) prior covariance (rotation rad, translation m).
        pixel_sigma_px: 1-sigma keypoint noise, ideal pixels.
        huber_sigmas: Huber threshold in sigmas.
        iterations: Gauss-Newton iterations.

    Returns:
        :class:`PoseRefinement`.
    """
    P = check_array("points_w", points_w, (None, 3))
    n = len(P)
    C = np.nan_to_num(check_array("point_covariance", point_covariance, (n, 3, 3)))
    uv = check_array("uv", uv, (n, 2), finite=True)
    T0 = check_transform("T_w_c_prior", T_w_c_prior)
    S0 = check_array("prior_covariance", prior_covariance, (6, 6), finite=True)
    info_prior = np.linalg.inv(S0)
    ideal = camera.undistort_points(uv)
    f = np.array([camera.fx, camera.fy])
    c = np.array([camera.cx, camera.cy])

    def residuals(T):
        R_cw = T[:3, :3].T
        p_c = (P - T[:3, 3]) @ R_cw.T
        with np.errstate(divide="ignore", invalid="ignore"):
            proj = f * p_c[:, :2] / p_c[:, 2:3] + c
        return p_c, proj - ideal, R_cw

    def jacobians(p_c, R_cw):
        S = sandwich2(point_jacobian(p_c, f[0], f[1], np.broadcast_to(R_cw, (n, 3, 3))), C)
        S[:, 0, 0] += pixel_sigma_px**2
        S[:, 1, 1] += pixel_sigma_px**2
        return image_pose_jacobian(p_c, f[0], f[1]), inv2(S)

    delta = np.zeros(6)
    T = T0
    for _ in range(iterations):
        p_c, r, R_cw = residuals(T)
        front = p_c[:, 2] > 0
        J, S_inv = jacobians(np.where(front[:, None], p_c, 1.0), R_cw)
        r0 = np.nan_to_num(r)
        e = np.sqrt(np.maximum(quad2(r0, S_inv), 0.0))
        w = np.where(front & np.isfinite(e), np.where(e <= huber_sigmas, 1.0, huber_sigmas / np.maximum(e, 1e-12)), 0.0)
        H, g = _normal_equations(J, S_inv, w, r0)
        H = H + info_prior
        g = g + info_prior @ delta
        step = -np.linalg.solve(H, g)
        delta = delta + step
        T = T0 @ _exp(delta)
        if np.max(np.abs(step)) < 1e-9:
            break
    p_c, r, R_cw = residuals(T)
    front = p_c[:, 2] > 0
    J, S_inv = jacobians(np.where(front[:, None], p_c, 1.0), R_cw)
    e = np.sqrt(np.maximum(quad2(np.nan_to_num(r, nan=1e6), S_inv), 0))
    inlier = front & np.isfinite(e)
    w = np.where(inlier, np.where(e <= huber_sigmas, 1.0, huber_sigmas / np.maximum(e, 1e-12)), 0.0)
    H = _normal_equations(J, S_inv, w, np.zeros((n, 2)))[0] + info_prior
    cov = np.linalg.inv(H)
    return PoseRefinement(T, 0.5 * (cov + cov.T), inlier, np.where(front, e, np.inf), np.linalg.norm(r, axis=1))
