"""The camera's rotation between two instants from the gyroscope alone (no gtsam).

A tracking front end (:class:`matchers.KltTracker`) predicts where its corners land from
the rotation since the previous frame; the rotation is all a prediction needs (the
translation's effect depends on the unknown depth) and the gyroscope gives it to within
its bias times the interval (EuRoC: about 0.02 rad/s x 50 ms = 1 mrad = 0.5 px).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.checks import check_array

from ..frame import ImuData


def gyro_rotation(imu: ImuData, t0: float, t1: float, gyro_bias=None) -> np.ndarray | None:
    """The IMU's rotation from ``t0`` to ``t1`` seconds, integrated from its angular rate.

    The rate is interpolated linearly at ``t0``, ``t1`` and taken at every sample between
    them; each piece is integrated with the midpoint rate (exact for a constant rate).

    Args:
        imu: the samples (rad/s in the IMU frame).
        t0, t1: seconds, ``t0 <= t1``.
        gyro_bias: (3,) rad/s subtracted from every sample, or None (zero).

    Returns:
        (3, 3) ``R_i0_i1``: the IMU frame at ``t1`` in the IMU frame at ``t0``
        (``R_w_i1 = R_w_i0 @ R_i0_i1``); None when the samples do not cover the interval.
    """
    bias = np.zeros(3) if gyro_bias is None else check_array("gyro_bias", gyro_bias, (3,), finite=True)
    t = imu.t
    if not t1 >= t0:
        raise ValueError(f"gyro_rotation: t1 {t1} before t0 {t0}")
    if len(t) == 0 or t0 < t[0] or t1 > t[-1]:
        return None
    # only the samples around the interval: a stream's samples grow for as long as it runs
    i0 = max(int(np.searchsorted(t, t0, side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(t, t1, side="left")) + 1, len(t))
    ts, gyro = t[i0:i1], imu.gyro[i0:i1]
    knots = np.concatenate([[t0], ts[(ts > t0) & (ts < t1)], [t1]])
    rate = np.stack([np.interp(knots, ts, gyro[:, k]) for k in range(3)], axis=1) - bias
    steps = 0.5 * (rate[1:] + rate[:-1]) * np.diff(knots)[:, None]  # (K, 3) rotation vectors, radians
    R = np.eye(3)
    for dR in Rotation.from_rotvec(steps).as_matrix():  # a handful of samples per camera frame
        R = R @ dR
    return R


def camera_rotation(imu: ImuData, t_prev: float, t_cur: float, gyro_bias=None) -> np.ndarray | None:
    """``R_cur_prev``: the previous camera's frame into the current camera's (``x_cur = R x_prev``).

    Args:
        imu: the samples; its ``T_c_i`` maps the IMU frame into the camera frame.
        t_prev, t_cur: the two frames' timestamps, seconds.
        gyro_bias: see :func:`gyro_rotation`.

    Returns:
        (3, 3), or None when the samples do not cover the interval.
    """
    R_i0_i1 = gyro_rotation(imu, t_prev, t_cur, gyro_bias)
    if R_i0_i1 is None:
        return None
    R_c_i = np.asarray(imu.T_c_i, float)[:3, :3]
    return R_c_i @ R_i0_i1.T @ R_c_i.T
