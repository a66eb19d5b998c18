"""Jacobians of the pinhole projection for the batched triangulation and pose refinement:
d(ideal pixel)/d(world point) and d(ideal pixel)/d(pose), their sandwich with a covariance, and
the per-observation normal-equation terms -- each row by row in closed form.

numpy's stacked matrix product costs ~0.3 us a matrix whatever its size, more than the few
products a (2, 3) or (2, 6) Jacobian needs: on 74 window triangulations of the 752x564 ASL loop
(2 000-6 400 observations) these closed forms took a call from 34 to 25 ms (docs/benchmarks.md
"The worker's keyframe update, 2026-12-07 (late)"). Pose perturbations follow GTSAM:
``T_w_c * Exp(xi)``, ``xi = (rotation rad, translation m)`` in the camera frame.
"""

from __future__ import annotations

import numpy as np

from vio_core.checks import check_array

_EYE3 = np.eye(3)


def _skew_batch(p: np.ndarray) -> np.ndarray:
    """(N, 3, 3) cross-product matrices of ``p: (N, 3)``."""
    z = np.zeros(len(p))
    return np.stack([np.stack([z, -p[:, 2], p[:, 1]], 1),
                     np.stack([p[:, 2], z, -p[:, 0]], 1),
                     np.stack([-p[:, 1], p[:, 0], z], 1)], 1)


def point_jacobian(p_c: np.ndarray, fx, fy, R_cw: np.ndarray) -> np.ndarray:
    """(N, 2, 3) d(ideal pixel)/d(world point) at camera points ``p_c: (N, 3)`` metres, for
    rotations ``R_cw: (N, 3, 3)`` (world to camera) and focal lengths ``fx, fy`` (pixels,
    scalars or (N,)): ``[[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]] @ R_cw``, row by row
    without a stacked matrix product (numpy's costs ~0.3 us a matrix, more than these few
    products: the triangulation of a window's 4 000 observations went from 34 to 25 ms)."""
    p_c = check_array("p_c", p_c, (None, 3))
    R_cw = check_array("R_cw", R_cw, (len(p_c), 3, 3))
    x, y, z = p_c[:, 0], p_c[:, 1], p_c[:, 2]
    iz = 1.0 / z
    a, b = fx * iz, fy * iz
    c, d = -a * x * iz, -b * y * iz
    J = np.empty((len(p_c), 2, 3))
    J[:, 0] = a[:, None] * R_cw[:, 0] + c[:, None] * R_cw[:, 2]
    J[:, 1] = b[:, None] * R_cw[:, 1] + d[:, None] * R_cw[:, 2]
    return J


def image_pose_jacobian(p_c: np.ndarray, fx, fy) -> np.ndarray:
    """(N, 2, 6) d(ideal pixel)/d xi at camera points ``p_c: (N, 3)`` metres (``T_w_c * Exp(xi)``,
    rotation rad first, then metres; focal lengths ``fx, fy`` in pixels, scalars or (N,)):
    the projection's Jacobian (:func:`point_jacobian`'s, without ``R_cw``) times
    :func:`pose_jacobian`, in closed form."""
    p_c = check_array("p_c", p_c, (None, 3))
    x, y, z = p_c[:, 0], p_c[:, 1], p_c[:, 2]
    iz = 1.0 / z
    a, b = fx * iz, fy * iz
    c, d = -a * x * iz, -b * y * iz
    J = np.empty((len(p_c), 2, 6))
    # [[a, 0, c], [0, b, d]] @ [skew(p_c) | -I]
    J[:, 0, 0] = -c * y
    J[:, 0, 1] = c * x - a * z
    J[:, 0, 2] = a * y
    J[:, 0, 3] = -a
    J[:, 0, 4] = 0.0
    J[:, 0, 5] = -c
    J[:, 1, 0] = b * z - d * y
    J[:, 1, 1] = d * x
    J[:, 1, 2] = -b * x
    J[:, 1, 3] = 0.0
    J[:, 1, 4] = -b
    J[:, 1, 5] = -d
    return J


def sandwich2(J: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(N, 2, 2) ``J_n C_n J_n^T`` of ``J: (N, 2, k)`` and symmetric ``C: (N, k, k)`` (one stacked
    product instead of two; the result exactly symmetric)."""
    J = check_array("J", J, (None, 2, None))
    C = check_array("C", C, (len(J), J.shape[2], J.shape[2]))
    W = J @ C
    S = np.empty((len(J), 2, 2))
    S[:, 0, 0] = np.einsum("ij,ij->i", W[:, 0], J[:, 0])
    S[:, 1, 1] = np.einsum("ij,ij->i", W[:, 1], J[:, 1])
    S[:, 0, 1] = S[:, 1, 0] = np.einsum("ij,ij->i", W[:, 0], J[:, 1])
    return S


def normal_terms(J: np.ndarray, S_inv: np.ndarray, r: np.ndarray | None = None):
    """Per observation, row by row in closed form, of ``J: (N, 2, 3)``, symmetric ``S_inv: (N, 2, 2)``
    and ``r: (N, 2)``: ``J^T S^-1 J: (N, 3, 3)``, ``J^T S^-1 r: (N, 3)`` (None without ``r``) and
    ``J^T S^-1: (N, 3, 2)``."""
    j0, j1 = J[:, 0], J[:, 1]
    s00, s01, s11 = S_inv[:, 0, 0, None], S_inv[:, 0, 1, None], S_inv[:, 1, 1, None]
    JtS = np.empty((len(J), 3, 2))
    w0 = JtS[:, :, 0] = s00 * j0 + s01 * j1
    w1 = JtS[:, :, 1] = s01 * j0 + s11 * j1
    H = j0[:, :, None] * w0[:, None, :] + j1[:, :, None] * w1[:, None, :]
    return H, None if r is None else w0 * r[:, :1] + w1 * r[:, 1:], JtS


def pose_jacobian(p_c) -> np.ndarray:
    """(N, 3, 6) d(point in camera)/d xi for ``T_w_c * Exp(xi)``, at ``p_c: (N, 3)`` metres.

    ``xi = (rotation rad, translation m)`` in the camera frame (GTSAM's ``Pose3``
    retraction): the camera point moves by ``p_c x omega - nu`` to first order.
    """
    p_c = check_array("p_c", p_c, (None, 3))
    J = np.zeros((len(p_c), 3, 6))
    J[:, :, :3] = _skew_batch(p_c)
    J[:, :, 3:] = -_EYE3
    return J


def depth_variance(a: np.ndarray, Pa: np.ndarray, p_c: np.ndarray, C: np.ndarray | None = None,
                   JtS: np.ndarray | None = None, J_pose: np.ndarray | None = None,
                   cross: np.ndarray | None = None) -> np.ndarray:
    """(N,) first-order variance of the depth of N triangulated points in one observing camera.

    Args:
        a: (N, 3) the camera's z axis in the world (``R_cw[2]``: d depth / d point).
        Pa: (N, 3) the point's world covariance times ``a``.
        p_c: (N, 3) metres, the points in the camera.
        C: (N, 6, 6) covariance of the camera's pose (``T_w_c * Exp(xi)``), or None (exact).
        JtS: (N, 3, 2) ``J_X^T S^-1`` of the observation in this camera (:func:`normal_terms`).
        J_pose: (N, 2, 6) its image pose Jacobian (:func:`image_pose_jacobian`).
        cross: (N,) bool, the observations that took part in the point's estimate (their
            pose error moved the point: a cross term), or None (all).

    Returns:
        ``a^T P a`` plus, with a pose covariance, the pose's own term ``b^T C b`` (``b`` = d
        depth / d xi, row z of :func:`pose_jacobian`) and twice the cross term ``a^T P J_X^T
        S^-1 J_pose C b``.
    """
    var = np.einsum("ni,ni->n", a, Pa)
    if C is None:
        return var
    b = np.zeros((len(p_c), 6))  # dz/dxi: row z of pose_jacobian, [-y, x, 0, 0, 0, -1]
    b[:, 0], b[:, 1], b[:, 5] = -p_c[:, 1], p_c[:, 0], -1.0
    Sb = np.einsum("nkl,nl->nk", C, b)  # pairwise contractions: one 5-operand einsum is 10x slower
    var = var + np.einsum("ni,ni->n", b, Sb)
    q = np.einsum("nj,njk->nk", Pa, JtS)  # (N, 2)
    term = np.einsum("nk,nk->n", q[:, 0, None] * J_pose[:, 0] + q[:, 1, None] * J_pose[:, 1], Sb)
    return var + 2.0 * (term if cross is None else np.where(cross, term, 0.0))
