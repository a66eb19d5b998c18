"""Small rigid-body helpers shared by the pipeline, loaders and simulators.

Conventions: ``T_a_b`` is a (4, 4) transform mapping points expressed in frame ``b``
into frame ``a`` (so ``T_w_c`` is camera-to-world). Quaternions are ``(qx, qy, qz, qw)``
as in the TUM trajectory format. Translations are metres, angles radians unless a name
says ``_deg``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .checks import check_array, check_transform


def make_transform(R, t) -> np.ndarray:
    """Build a (4, 4) transform from ``R: (3, 3)`` and ``t: (3,) metres``."""
    R = check_array("R", R, (3, 3), finite=True)
    t = check_array("t", t, (3,), finite=True)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def invert_transform(T) -> np.ndarray:
    """Inverse of a rigid (4, 4) transform ``T_a_b`` -> ``T_b_a``."""
    T = check_array("T", T, (4, 4), finite=True)
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def relative_transform(T_w_a, T_w_b) -> np.ndarray:
    """``T_a_b`` from two camera-to-world poses ``T_w_a``, ``T_w_b`` ((4, 4) each)."""
    return invert_transform(T_w_a) @ check_array("T_w_b", T_w_b, (4, 4), finite=True)


def rotation_angle_deg(R) -> float:
    """Angle (degrees) of the rotation ``R: (3, 3)``."""
    R = check_array("R", R, (3, 3), finite=True)
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(c)))


def transform_points(T_a_b, points_b) -> np.ndarray:
    """Map ``points_b: (N, 3)`` (metres, frame b) into frame a with ``T_a_b: (4, 4)``."""
    T = check_array("T_a_b", T_a_b, (4, 4))
    p = check_array("points_b", points_b, (None, 3))
    return p @ T[:3, :3].T + T[:3, 3]


def transform_from_tum(values) -> np.ndarray:
    """(4, 4) transform from a TUM row ``(tx, ty, tz, qx, qy, qz, qw)`` (metres, unit quaternion)."""
    v = check_array("values", values, (7,), finite=True)
    q = v[3:]
    n = np.linalg.norm(q)
    if not 0.99 < n < 1.01:
        raise ValueError(f"quaternion norm {n:.4f} is not 1")
    return make_transform(Rotation.from_quat(q / n).as_matrix(), v[:3])


def transform_to_tum(T) -> np.ndarray:
    """TUM row ``(tx, ty, tz, qx, qy, qz, qw)`` of a (4, 4) transform."""
    T = check_transform("T", T)
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_quat()])


def skew(v) -> np.ndarray:
    """(3, 3) cross-product matrix of ``v: (3,)``."""
    x, y, z = check_array("v", v, (3,))
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def skews(v) -> np.ndarray:
    """(..., 3, 3) cross-product matrices of a stack of vectors ``v: (..., 3)`` (no checks: hot paths)."""
    v = np.asarray(v, dtype=np.float64)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


#: below this angle (rad) the Rodrigues coefficients are their Taylor series
_SMALL_ANGLE = 1e-6
#: within this angle (rad) of pi the logarithm goes through scipy (R - R^T loses the axis there)
_NEAR_PI = 1e-3


def so3_exp(phi) -> np.ndarray:
    """(..., 3, 3) rotation matrices of rotation vectors ``phi: (..., 3)`` rad (Rodrigues,
    batched; for the small stacks of hot loops, where scipy's ``Rotation`` costs more than the maths)."""
    phi = np.asarray(phi, dtype=np.float64)
    theta = np.linalg.norm(phi, axis=-1)
    small = theta < _SMALL_ANGLE
    th = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(th) / th)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(th)) / th**2)
    K = skews(phi)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def so3_log(R) -> np.ndarray:
    """(..., 3) rotation vectors (rad, angle in [0, pi]) of rotation matrices ``R: (..., 3, 3)``
    (batched inverse of :func:`so3_exp`; rotations within 1e-3 rad of pi go through scipy)."""
    R = np.asarray(R, dtype=np.float64)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    small = theta < _SMALL_ANGLE
    f = np.where(small, 0.5 + theta**2 / 12.0, theta / (2.0 * np.sin(np.where(small, 1.0, theta))))
    out = v * f[..., None]
    near_pi = theta > np.pi - _NEAR_PI
    if np.any(near_pi):
        out[near_pi] = Rotation.from_matrix(R[near_pi]).as_rotvec()
    return out


def invert_transforms(T) -> np.ndarray:
    """Inverses of a stack of rigid transforms ``T: (N, 4, 4)`` ``T_a_b`` -> ``T_b_a`` (N, 4, 4)."""
    T = check_array("T", T, (None, 4, 4), finite=True)
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    out = np.zeros_like(T)
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def adjoints(T) -> np.ndarray:
    """(N, 6, 6) :func:`adjoint` of each rigid transform of ``T: (N, 4, 4)``."""
    T = check_array("T", T, (None, 4, 4), finite=True)
    R, t = T[:, :3, :3], T[:, :3, 3]
    S = skews(t)
    A = np.zeros((len(T), 6, 6))
    A[:, :3, :3] = R
    A[:, 3:, :3] = S @ R
    A[:, 3:, 3:] = R
    return A


def adjoint(T) -> np.ndarray:
    """(6, 6) adjoint of the rigid transform ``T: (4, 4)`` in (rotation, translation) order:
    ``T Exp(xi) = Exp(adjoint(T) xi) T``, so a right-perturbation covariance ``S`` of a pose
    ``T_a_b Exp(xi)`` is ``adjoint(T_a_b) S adjoint(T_a_b)^T`` as a left one in ``a``."""
    return adjoints(check_transform("T", T)[None])[0]
