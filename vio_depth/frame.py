"""The input records of the pipeline: one :class:`Frame` per image, :class:`ImuData` per sequence.

Loaders (:mod:`vio_depth.io`) produce them, every stage reads them. Pixel data load lazily.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array
from vio_core.errors import InputError, ShapeError

#: IMU samples beyond these magnitudes are refused as corrupt: MEMS and tactical IMUs
#: saturate at 35 rad/s (2000 deg/s) and 16-200 g; these bounds leave a wide margin and
#: keep the preintegration finite (issue 12: 1e30 values ended in NaN rotations)
MAX_GYRO_RAD_S = 100.0
MAX_ACCEL_M_S2 = 2000.0
#: the magnitude of gravity a sequence may declare, m/s^2: Earth's surface gravity lies in
#: 9.78-9.83 (equator to pole, sea level); a wrong vector (``[0, 0, 0]``, or g in other units)
#: gave 4 frames at AbsRel 1.54 with exit 0 (issue 23)
GRAVITY_RANGE_M_S2 = (9.7, 9.9)
#: the calibration fields of :class:`ImuData` and their meaning (all must be finite and > 0)
_NOISE_FIELDS = {"gyro_noise": "gyro_noise_density", "accel_noise": "accel_noise_density",
                 "gyro_bias_walk": "gyro_bias_random_walk", "accel_bias_walk": "accel_bias_random_walk"}


def imu_calibration_problem(gyro_noise: float, accel_noise: float, gyro_bias_walk: float, accel_bias_walk: float,
                            gravity_w) -> str:
    """Why an IMU calibration is refused ("" when it is not): a noise density or bias random
    walk that is not finite and > 0, or a gravity vector whose magnitude lies outside
    :data:`GRAVITY_RANGE_M_S2`. The message starts with the sequence-file key
    (``gyro_noise_density must be ...``). The one check of every loader's IMU calibration."""
    values = {"gyro_noise": gyro_noise, "accel_noise": accel_noise, "gyro_bias_walk": gyro_bias_walk,
              "accel_bias_walk": accel_bias_walk}
    for name, v in values.items():
        if not (np.isfinite(v) and v > 0):
            return f"{_NOISE_FIELDS[name]} must be finite and > 0, got {v!r}"
    g = np.asarray(gravity_w, dtype=np.float64)
    lo, hi = GRAVITY_RANGE_M_S2
    norm = float(np.linalg.norm(g)) if g.shape == (3,) and np.all(np.isfinite(g)) else float("nan")
    if not lo <= norm <= hi:
        return (f"gravity_w {g.tolist()} has magnitude {norm:.4g} m/s^2; Earth's gravity is {lo}-{hi} m/s^2 "
                "(a vector in m/s^2 pointing down in the world frame, e.g. [0, 0, -9.81])")
    return ""


def imu_sample_problem(gyro: np.ndarray, accel: np.ndarray) -> tuple[int, str] | None:
    """``(index, why)`` of the first IMU sample beyond :data:`MAX_GYRO_RAD_S` /
    :data:`MAX_ACCEL_M_S2` (``gyro``, ``accel``: (M, 3)), or None when all are plausible."""
    w = np.linalg.norm(gyro, axis=1)
    a = np.linalg.norm(accel, axis=1)
    bad = np.flatnonzero(~((w <= MAX_GYRO_RAD_S) & (a <= MAX_ACCEL_M_S2)))
    if not len(bad):
        return None
    i = int(bad[0])
    if not w[i] <= MAX_GYRO_RAD_S:
        return i, f"gyro |w| = {w[i]:.3g} rad/s is beyond the plausible {MAX_GYRO_RAD_S:g} rad/s"
    return i, f"accel |a| = {a[i]:.3g} m/s^2 is beyond the plausible {MAX_ACCEL_M_S2:g} m/s^2"


@dataclass(frozen=True)
class ImuData:
    """IMU samples of a whole sequence (small: loaded eagerly, unlike images).

    Attributes:
        t: (M,) seconds, strictly increasing, same clock as frame timestamps.
        gyro: (M, 3) rad/s, angular rate in the IMU frame.
        accel: (M, 3) m/s^2, specific force in the IMU frame (includes -gravity,
            i.e. a resting IMU with z up reads about +9.81 on z).
        T_c_i: (4, 4) IMU-to-camera transform (maps IMU-frame points into the camera frame).
        gyro_noise: rad/s/sqrt(Hz) white-noise density.
        accel_noise: m/s^2/sqrt(Hz) white-noise density.
        gyro_bias_walk: rad/s^2/sqrt(Hz) bias random walk.
        accel_bias_walk: m/s^3/sqrt(Hz) bias random walk.
        gravity: m/s^2 magnitude; the world frame's gravity direction is given by
            ``gravity_w`` ((3,), default -z).
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    T_c_i: np.ndarray
    gyro_noise: float = 1.7e-4
    accel_noise: float = 2.0e-3
    gyro_bias_walk: float = 2.0e-5
    accel_bias_walk: float = 3.0e-3
    gravity_w: tuple[float, float, float] = (0.0, 0.0, -9.81)

    def __post_init__(self):
        t = check_array("imu.t", self.t, (None,), finite=True)
        check_array("imu.gyro", self.gyro, (len(t), 3), finite=True)
        check_array("imu.accel", self.accel, (len(t), 3), finite=True)
        check_array("imu.T_c_i", self.T_c_i, (4, 4), finite=True)
        if len(t) > 1 and np.any(np.diff(t) <= 0):
            raise ShapeError("imu.t must be strictly increasing")
        problem = imu_sample_problem(np.asarray(self.gyro, float), np.asarray(self.accel, float))
        if problem is not None:
            i, why = problem
            raise InputError(f"imu sample {i} (t={t[i]:.6f} s): {why}")

    def window(self, t0: float, t1: float) -> "ImuData":
        """Samples with ``t0 <= t <= t1`` seconds, plus one on each side when available."""
        i0 = max(0, int(np.searchsorted(self.t, t0, side="right")) - 1)
        i1 = min(len(self.t), int(np.searchsorted(self.t, t1, side="left")) + 1)
        return ImuData(self.t[i0:i1], self.gyro[i0:i1], self.accel[i0:i1], self.T_c_i,
                       self.gyro_noise, self.accel_noise, self.gyro_bias_walk,
                       self.accel_bias_walk, self.gravity_w)


@dataclass
class Frame:
    """One image of a sequence with everything known about it; pixel data load lazily.

    Attributes:
        index: 0-based position in the sequence.
        timestamp: seconds.
        stem: image file stem, used to name outputs (``depth/<stem>.png``).
        camera: intrinsics of this image.
        T_w_c: (4, 4) camera-to-world pose in metres, or None when unknown.
        velocity_w: (3,) m/s world-frame velocity of the IMU when the dataset gives it
            (KITTI OXTS), else None.
    """

    index: int
    timestamp: float
    stem: str
    camera: Camera
    T_w_c: np.ndarray | None
    load_image: Callable[[], np.ndarray] = field(repr=False)
    load_gt_depth: Callable[[], np.ndarray] | None = field(default=None, repr=False)
    velocity_w: np.ndarray | None = None

    def image(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB image."""
        return self.load_image()

    def gt_depth(self) -> np.ndarray | None:
        """(H, W) float32 metres, 0 = invalid; None when the sequence has no depth."""
        return None if self.load_gt_depth is None else self.load_gt_depth()
