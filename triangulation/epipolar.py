"""The epipolar geometry of two views with a known relative pose, for ideal (undistorted) pixels.

``x_ref^T F x_cur = 0`` with ``F = K_ref^-T [t]x R K_cur^-1`` (``cur``: the current camera,
``ref``: the reference one; ``T_ref_cur = (R, t)`` maps current-camera points into the
reference camera, metres):

* :func:`fundamental_from_pose`: F, unit Frobenius norm;
* :func:`sampson_distance`: the first-order distance (pixels) of a match to the geometry;
* :func:`correct_matches`: Lindstrom's optimal correction (``niter2``, CVPR 2010) of a
  match onto it.

The private kernels take homogeneous or batched inputs (a leading dimension of poses, each
with its own F) for :mod:`.triangulate`'s numerical Jacobians, and avoid numpy's generic
overhead on rows of 2 or 3 while keeping its arithmetic order (results bit for bit equal).
"""

from __future__ import annotations

import numpy as np

from vio_core.checks import check_array, check_transform
from vio_core.geometry import skews

# Sampson distance: below this resolution (pixels) floating-point rounding dominates
_SAMPSON_RESOLUTION_PX = 1e-3
_ROUNDING_FACTOR = 1e3


def fundamental_from_pose(T_ref_cur, K_cur, K_ref) -> np.ndarray:
    """(3, 3) fundamental matrix with ``x_ref^T F x_cur = 0`` for ideal pixels.

    Args:
        T_ref_cur: (4, 4) current-camera-to-reference-camera transform, metres.
        K_cur, K_ref: (3, 3) intrinsics in pixels.

    Returns ``F = K_ref^-T [t]x R K_cur^-1`` scaled to unit Frobenius norm (the baseline
    length does not matter; the Sampson distance is scale-invariant). A zero baseline
    gives the zero matrix.
    """
    T = check_transform("T_ref_cur", T_ref_cur)
    K_cur = check_array("K_cur", K_cur, (3, 3), finite=True)
    K_ref = check_array("K_ref", K_ref, (3, 3), finite=True)
    return _fundamental(T[:3, :3], T[:3, 3], np.linalg.inv(K_cur), np.linalg.inv(K_ref))


def _fundamental(R, t, K_cur_inv, K_ref_inv) -> np.ndarray:
    """(..., 3, 3) unit-norm fundamental matrices of poses ``R: (..., 3, 3)``, ``t: (..., 3)``."""
    F = K_ref_inv.T @ skews(t) @ R @ K_cur_inv
    flat = F.reshape(F.shape[:-2] + (1, 9))
    norm = np.sqrt((flat @ np.swapaxes(flat, -1, -2))[..., 0])  # (..., 1): |F|, a BLAS dot as np.linalg.norm
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(norm[..., None] > 0, F / norm[..., None], F)


def sampson_distance(F, uv_cur, uv_ref) -> np.ndarray:
    """(N,) Sampson distance in pixels of ideal-pixel matches ``uv_cur, uv_ref: (N, 2)``.

    ``F: (3, 3)`` with ``x_ref^T F x_cur = 0``. It is the first-order approximation of the
    total geometric distance ``sqrt(|dx_cur|^2 + |dx_ref|^2)`` needed to put the match on
    the epipolar geometry. NaN where undefined: F = 0, or a match sitting on both epipoles
    (to within floating-point rounding), where the epipolar lines degenerate.
    """
    F = check_array("F", F, (3, 3), finite=True)
    uv_cur = check_array("uv_cur", uv_cur, (None, 2))
    uv_ref = check_array("uv_ref", uv_ref, (len(uv_cur), 2))
    return _sampson(F, _homogeneous(uv_cur), _homogeneous(uv_ref))


def _sampson(F, xc, xr) -> np.ndarray:
    """:func:`sampson_distance` of homogeneous ideal pixels ``xc, xr: (N, 3)``."""
    Fxc = xc @ F.T  # epipolar lines in the reference image
    Ftxr = xr @ F  # epipolar lines in the current image
    err = _rowdot(xr, Fxc)
    grad = np.sqrt(Fxc[:, 0] ** 2 + Fxc[:, 1] ** 2 + Ftxr[:, 0] ** 2 + Ftxr[:, 1] ** 2)
    # rounding bound of err (generous: F itself carries rounding error); the distance is
    # undefined where that bound alone would move it by more than _SAMPSON_RESOLUTION_PX
    bound = _ROUNDING_FACTOR * np.finfo(np.float64).eps * _rowdot(np.abs(xr), np.abs(xc) @ np.abs(F).T)
    with np.errstate(divide="ignore", invalid="ignore"):
        defined = bound < _SAMPSON_RESOLUTION_PX * grad
        return np.where(defined, np.abs(err) / grad, np.nan)


def correct_matches(F, uv_cur, uv_ref) -> tuple[np.ndarray, np.ndarray]:
    """Optimal correction of ideal-pixel matches onto the epipolar geometry.

    Lindstrom's ``niter2`` (CVPR 2010): the smallest displacement (sum of squared
    pixels over both views) of ``uv_cur, uv_ref: (N, 2)`` after which
    ``x_ref^T F x_cur = 0``; ``F: (3, 3)``. Returns the corrected ``(uv_cur, uv_ref)``,
    each (N, 2) pixels. A point with undefined geometry (at both epipoles) is left as is.
    """
    F = check_array("F", F, (3, 3), finite=True)
    uv_cur = check_array("uv_cur", uv_cur, (None, 2))
    uv_ref = check_array("uv_ref", uv_ref, (len(uv_cur), 2))
    return _correct(F, uv_cur, uv_ref)


def _homogeneous(uv) -> np.ndarray:
    """(..., N, 3): pixels ``uv: (..., N, 2)`` with a third coordinate 1."""
    x = np.empty(uv.shape[:-1] + (3,))
    x[..., :2] = uv
    x[..., 2] = 1.0
    return x


def _cross(a, b) -> np.ndarray:
    """``np.cross`` of two (N, 3) float64 arrays: the same products and differences in the
    same order, without its generic overhead (axis moves)."""
    out = np.empty((len(a), 3))
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    np.multiply(a1, b2, out=out[:, 0])
    out[:, 0] -= a2 * b1
    np.multiply(a2, b0, out=out[:, 1])
    out[:, 1] -= a0 * b2
    np.multiply(a0, b1, out=out[:, 2])
    out[:, 2] -= a1 * b0
    return out


def _rowdot(a, b) -> np.ndarray:
    """(...,) ``sum(a * b, axis=-1)`` for a short last axis (2 or 3), summed left to right
    as ``np.sum`` does there (bit-identical), without its slow reduction over tiny rows."""
    out = a[..., 0] * b[..., 0]
    for k in range(1, a.shape[-1]):
        out = out + a[..., k] * b[..., k]
    return out


def _correct(F, uv_cur, uv_ref):
    """Lindstrom's ``niter2`` for ``F: (..., 3, 3)`` and pixels ``uv_cur, uv_ref: (..., N, 2)``.

    Leading dimensions broadcast: one fundamental matrix per batch of matches (the pose
    Jacobian corrects the same matches under twelve perturbed poses in one call).
    """
    # Lindstrom's notation: x = x_ref, x' = x_cur, E = F, S = [I2 0].
    xc = _homogeneous(uv_cur)
    xr = _homogeneous(uv_ref)
    F2 = F[..., :2, :2]
    lines_ref = xc @ np.swapaxes(F, -1, -2)  # F x': epipolar lines in the reference image
    n_r = lines_ref[..., :2]  # S F x'
    n_c = (xr @ F)[..., :2]  # S F^T x
    # a = n_r^T F2 n_c, the products and their order as np.einsum("ni,ij,nj->n") forms them
    F2b = F2[..., None, :, :]  # (..., 1, 2, 2): broadcasts over the matches
    a = (n_r[..., 0] * F2b[..., 0, 0] * n_c[..., 0] + n_r[..., 0] * F2b[..., 0, 1] * n_c[..., 1]
         + n_r[..., 1] * F2b[..., 1, 0] * n_c[..., 0] + n_r[..., 1] * F2b[..., 1, 1] * n_c[..., 1])
    b = 0.5 * (_rowdot(n_r, n_r) + _rowdot(n_c, n_c))
    c = _rowdot(xr, lines_ref)
    d = np.sqrt(np.maximum(b * b - a * c, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(b + d > 0, c / (b + d), 0.0)[..., None]
        dr = lam * n_r
        dc = lam * n_c
        n_r = n_r - dc @ np.swapaxes(F2, -1, -2)
        n_c = n_c - dr @ F2
        nn = _rowdot(n_r, n_r) + _rowdot(n_c, n_c)
        lam = np.where(nn > 0, lam[..., 0] * 2.0 * d / nn, 0.0)[..., None]
    return uv_cur - lam * n_c, uv_ref - lam * n_r
