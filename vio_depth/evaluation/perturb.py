"""Seeded perturbations for the robustness studies (the paper's robustness figure and more).

Every function is pure and vectorised: it takes arrays (or an :class:`~vio_depth.frame.ImuData`)
and a ``seed`` (an int or a sequence of ints, e.g. ``[seed, frame.index]`` so a frame's draw
does not depend on which other frames ran), and returns new values; inputs are never
modified. The studies (:data:`STUDIES`) name each perturbation's parameter and default sweep.

* :func:`depth_noise` -- relative Gaussian noise on the sparse depths;
* :func:`shift_pixels` -- the sparse points shifted against the image (calibration error
  between the point sensor and the camera, or keypoint localisation error);
* :func:`lidar_points` -- a simulated ``n``-beam LiDAR (the paper's 1 / 16 / 32 beams);
* :func:`add_outliers` -- a fraction of the points replaced by wrong depths;
* :func:`perturb_imu` -- noisier IMU samples (noise densities scaled consistently) plus biases;
* :func:`perturb_pose` -- camera poses with Gaussian rotation / translation errors;
* :class:`PerturbedSequence` -- a sequence whose poses (per frame) and IMU are perturbed.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple
from typing import Sequence as Seq

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.checks import check_array
from vio_core.errors import SettingsError

from ..frame import Frame, ImuData
from ..io.base import Sequence
from .reference_points import lidar_beams

SeedLike = int | Seq[int]


def _rng(seed: SeedLike) -> np.random.Generator:
    return np.random.default_rng(seed)


def _non_negative(name: str, value: float) -> float:
    if not (isinstance(value, (int, float, np.floating, np.integer)) and value >= 0 and np.isfinite(value)):
        raise SettingsError(f"{name} must be a finite number >= 0, got {value!r}")
    return float(value)


def depth_noise(depth, rel_sigma: float, seed: SeedLike) -> np.ndarray:
    """Multiplicative Gaussian noise: ``depth * (1 + rel_sigma * n)``, ``n ~ N(0, 1)`` per point.

    Args:
        depth: (N,) metres.
        rel_sigma: relative standard deviation (0.05 = 5 % of each depth), >= 0.
        seed: seed of the draw.

    Returns:
        (N,) float64 metres; a draw that makes a depth <= 0 (``n <= -1/rel_sigma``) gives NaN
        (no depth), never a clipped value.
    """
    z = check_array("depth", depth, (None,)).astype(np.float64)
    s = _non_negative("rel_sigma", rel_sigma)
    out = z * (1.0 + s * _rng(seed).standard_normal(len(z)))
    with np.errstate(invalid="ignore"):
        return np.where(out > 0, out, np.nan)


def shift_pixels(uv, shift_px: float, seed: SeedLike, per_point: bool = False) -> np.ndarray:
    """Move points by ``shift_px`` pixels in a random direction.

    Args:
        uv: (N, 2) px.
        shift_px: length of the shift, pixels, >= 0.
        seed: seed of the direction(s).
        per_point: False (default): one direction for all points -- a systematic
            misregistration of the point sensor against the image; True: an independent
            direction per point.

    Returns:
        (N, 2) float64 px (may leave the image; callers drop points outside it).
    """
    p = check_array("uv", uv, (None, 2)).astype(np.float64)
    s = _non_negative("shift_px", shift_px)
    angle = _rng(seed).uniform(0.0, 2.0 * np.pi, len(p) if per_point else 1)
    return p + s * np.stack([np.cos(angle), np.sin(angle)], axis=1)


class SparsePoints(NamedTuple):
    """Sparse metric points: ``uv`` (N, 2) px ``(column, row)``, ``depth`` (N,) metres."""

    uv: np.ndarray
    depth: np.ndarray


def lidar_points(gt_depth, n_beams: int) -> SparsePoints:
    """Valid ground truth on ``n_beams`` evenly spaced rows (the paper's simulated LiDAR).

    Delegates to :func:`vio_depth.evaluation.reference_points.lidar_beams` (the ``--points lidar:N``
    source), so the study uses exactly the rows the pipeline uses.

    Args:
        gt_depth: (H, W) metres, 0 = invalid.
        n_beams: number of beams >= 1.
    """
    uv, depth = lidar_beams(gt_depth, int(n_beams))
    return SparsePoints(uv, depth)


class OutlierDraw(NamedTuple):
    """Result of :func:`add_outliers`: ``depth`` (N,) metres and ``is_outlier`` (N,) bool."""

    depth: np.ndarray
    is_outlier: np.ndarray


def add_outliers(depth, ratio: float, seed: SeedLike, min_depth: float, max_depth: float,
                 min_factor: float = 1.25) -> OutlierDraw:
    """Replace ``round(ratio * N)`` randomly chosen depths with wrong ones.

    An outlier's depth is log-uniform in ``[min_depth, max_depth]`` and differs from the
    point's depth by at least ``min_factor`` (ratio ``max(a/b, b/a) >= min_factor``; 1.25 is
    the delta1 threshold, so every outlier is wrong by the metrics' own definition). Draws
    that fall too close are redrawn (vectorised, at most 100 rounds).

    Args:
        depth: (N,) metres, > 0.
        ratio: fraction of outliers in [0, 1].
        seed: seed of the choice and the draws.
        min_depth, max_depth: metres, range of the outlier depths (``0 < min < max``).
        min_factor: >= 1; must leave room: ``max_depth / min_depth > min_factor**2``.

    Raises:
        SettingsError: invalid ratio, range or factor, or no valid draw possible for a point.
    """
    z = check_array("depth", depth, (None,)).astype(np.float64)
    if not 0.0 <= ratio <= 1.0:
        raise SettingsError(f"outlier ratio must be in [0, 1], got {ratio!r}")
    if not (0 < min_depth < max_depth) or not min_factor >= 1.0 or max_depth / min_depth <= min_factor**2:
        raise SettingsError(f"add_outliers: need 0 < min_depth < max_depth with max/min > min_factor^2, got "
                            f"[{min_depth}, {max_depth}] and min_factor {min_factor}")
    rng = _rng(seed)
    n_out = int(round(ratio * len(z)))
    idx = np.sort(rng.permutation(len(z))[:n_out])
    lo, hi = np.log(min_depth), np.log(max_depth)
    log_true = np.log(z[idx])
    draw = rng.uniform(lo, hi, n_out)
    for _ in range(100):
        bad = np.abs(draw - log_true) < np.log(min_factor)
        if not bad.any():
            break
        draw[bad] = rng.uniform(lo, hi, int(bad.sum()))
    else:
        raise SettingsError("add_outliers: could not draw outliers far enough from some depths")
    out = z.copy()
    out[idx] = np.exp(draw)
    mask = np.zeros(len(z), bool)
    mask[idx] = True
    return OutlierDraw(out, mask)


def perturb_imu(imu: ImuData, noise_scale: float, seed: SeedLike, gyro_bias=(0.0, 0.0, 0.0),
                accel_bias=(0.0, 0.0, 0.0)) -> ImuData:
    """Noisier IMU samples whose declared noise densities stay truthful.

    The four densities (white noise and bias random walk of gyro and accelerometer) are
    multiplied by ``s = noise_scale``; to the samples is added what makes their noise match:
    white noise of density ``density * sqrt(s^2 - 1)`` (per-sample standard deviation
    ``/ sqrt(dt)``) and a bias random walk of density ``walk * sqrt(s^2 - 1)`` (increments
    ``* sqrt(dt)``), ``dt`` = median sample interval; plus the constant ``gyro_bias``
    (rad/s) and ``accel_bias`` (m/s^2), which the densities do not describe (a bias the
    estimator must absorb).

    Args:
        imu: the sequence's IMU.
        noise_scale: ``s >= 1`` (noise cannot be removed; 1 = only the constant biases).
        seed: seed of the draws.
        gyro_bias: (3,) rad/s added to every gyro sample.
        accel_bias: (3,) m/s^2 added to every accelerometer sample.

    Returns:
        A new :class:`ImuData` (same times, ``T_c_i`` and gravity).
    """
    if not (np.isfinite(noise_scale) and noise_scale >= 1.0):
        raise SettingsError(f"noise_scale must be >= 1 (noise cannot be removed), got {noise_scale!r}")
    bg = check_array("gyro_bias", gyro_bias, (3,), finite=True)
    ba = check_array("accel_bias", accel_bias, (3,), finite=True)
    n = len(imu.t)
    dt = float(np.median(np.diff(imu.t))) if n > 1 else 1.0
    k = float(np.sqrt(noise_scale**2 - 1.0))
    rng = _rng(seed)
    white = rng.standard_normal((2, n, 3))
    walk = np.cumsum(rng.standard_normal((2, n, 3)), axis=1) * np.sqrt(dt)
    gyro = imu.gyro + bg + k * (imu.gyro_noise / np.sqrt(dt) * white[0] + imu.gyro_bias_walk * walk[0])
    accel = imu.accel + ba + k * (imu.accel_noise / np.sqrt(dt) * white[1] + imu.accel_bias_walk * walk[1])
    return replace(imu, gyro=gyro, accel=accel, gyro_noise=imu.gyro_noise * noise_scale,
                   accel_noise=imu.accel_noise * noise_scale, gyro_bias_walk=imu.gyro_bias_walk * noise_scale,
                   accel_bias_walk=imu.accel_bias_walk * noise_scale)


def perturb_pose(T_w_c, rot_sigma_deg: float, trans_sigma_m: float, seed: SeedLike) -> np.ndarray:
    """Camera poses with independent Gaussian errors in the camera frame.

    ``T' = T [Exp(dtheta) | dt]`` (right perturbation) with ``dtheta ~ N(0, rot_sigma^2 I)``
    (rotation vector, radians) and ``dt ~ N(0, trans_sigma^2 I)`` metres per pose. Each
    pose is perturbed independently, so the *relative* pose of two frames has errors
    ``sqrt(2)`` times larger.

    Args:
        T_w_c: (4, 4) or (N, 4, 4) camera-to-world poses, metres.
        rot_sigma_deg: per-axis rotation standard deviation, degrees, >= 0.
        trans_sigma_m: per-axis translation standard deviation, metres, >= 0.
        seed: seed of the draws.

    Returns:
        Array of the input's shape.
    """
    T = np.asarray(T_w_c, dtype=np.float64)
    single = T.ndim == 2
    T = check_array("T_w_c", T[None] if single else T, (None, 4, 4), finite=True)
    rs = np.radians(_non_negative("rot_sigma_deg", rot_sigma_deg))
    ts = _non_negative("trans_sigma_m", trans_sigma_m)
    rng = _rng(seed)
    dtheta = rs * rng.standard_normal((len(T), 3))
    dt = ts * rng.standard_normal((len(T), 3))
    delta = np.tile(np.eye(4), (len(T), 1, 1))
    delta[:, :3, :3] = Rotation.from_rotvec(dtheta).as_matrix()
    delta[:, :3, 3] = dt
    out = T @ delta
    return out[0] if single else out


@dataclass(frozen=True)
class PoseNoise:
    """Pose perturbation of :class:`PerturbedSequence`: per-axis sigmas (degrees, metres)."""

    rot_sigma_deg: float = 0.0
    trans_sigma_m: float = 0.0


@dataclass(frozen=True)
class ImuNoiseBoost:
    """IMU perturbation of :class:`PerturbedSequence` (see :func:`perturb_imu`)."""

    noise_scale: float = 1.0
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)


class PerturbedSequence(Sequence):
    """A view of ``base`` with perturbed poses and IMU; pixels, depth and disparity unchanged.

    Frame ``i``'s pose is :func:`perturb_pose` seeded with ``[seed, i]`` (the same whatever
    frames are read, and in which order); the IMU is :func:`perturb_imu` seeded with
    ``[seed, 2**32 - 1]`` (a stream no frame index uses), computed once.
    """

    def __init__(self, base: Sequence, seed: int, pose_noise: PoseNoise | None = None,
                 imu_noise: ImuNoiseBoost | None = None):
        self.base = base
        self.seed = int(seed)
        self.pose_noise = pose_noise
        self.imu_noise = imu_noise
        imu = base.imu
        if imu is not None and imu_noise is not None:
            imu = perturb_imu(imu, imu_noise.noise_scale, [self.seed, 2**32 - 1], imu_noise.gyro_bias,
                              imu_noise.accel_bias)
        super().__init__(base.root, base.name, base.camera, imu, base.disparity)
        self.format_name = base.format_name
        self.imu_missing_reason = base.imu_missing_reason

    def __len__(self) -> int:
        return len(self.base)

    @property
    def has_gt_depth(self) -> bool:
        return self.base.has_gt_depth

    def frame(self, index: int) -> Frame:
        f = self.base.frame(index)
        if self.pose_noise is None or f.T_w_c is None:
            return f
        T = perturb_pose(f.T_w_c, self.pose_noise.rot_sigma_deg, self.pose_noise.trans_sigma_m,
                         [self.seed, int(index)])
        return replace(f, T_w_c=T)


@dataclass(frozen=True)
class Study:
    """One robustness study: a perturbation swept over ``values`` (keyword arguments of ``function``).

    Attributes:
        name: study name (CSV / PNG file stem).
        function: name of the function in this module it drives.
        parameter: the swept quantity, for the x axis.
        unit: its unit.
        values: one dict of keyword arguments per point of the sweep (first = unperturbed).
    """

    name: str
    function: str
    parameter: str
    unit: str
    values: tuple[dict, ...]

    def x(self) -> list[float]:
        """The swept parameter's value at every point."""
        return [float(v[self.parameter]) for v in self.values]


def _sweep(key: str, values, **fixed) -> tuple[dict, ...]:
    return tuple({key: v, **fixed} for v in values)


#: Default sweeps. Pose noise sweeps the rotation sigma with translation sigma = 1 cm per 0.1 degree.
STUDIES: dict[str, Study] = {s.name: s for s in (
    Study("depth_noise", "depth_noise", "rel_sigma", "fraction of depth",
          _sweep("rel_sigma", (0.0, 0.01, 0.02, 0.05, 0.1, 0.2))),
    Study("pixel_shift", "shift_pixels", "shift_px", "px", _sweep("shift_px", (0.0, 1.0, 2.0, 4.0, 8.0, 16.0))),
    Study("lidar_beams", "lidar_points", "n_beams", "beams", _sweep("n_beams", (1, 2, 4, 8, 16, 32, 64))),
    Study("outliers", "add_outliers", "ratio", "fraction of points",
          _sweep("ratio", (0.0, 0.1, 0.2, 0.3, 0.5, 0.7))),
    Study("imu_noise", "perturb_imu", "noise_scale", "x noise densities",
          _sweep("noise_scale", (1.0, 2.0, 5.0, 10.0, 20.0, 50.0))),
    Study("pose_noise", "perturb_pose", "rot_sigma_deg", "deg (and 0.1 m/deg translation)",
          tuple({"rot_sigma_deg": r, "trans_sigma_m": 0.1 * r} for r in (0.0, 0.05, 0.1, 0.2, 0.5, 1.0))),
)}
