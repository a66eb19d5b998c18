"""Domain types shared across the pipeline.

Types that belong to one stage live with it and are re-exported here for convenience:
``Features``/``Matches`` in :mod:`matchers.base`, ``TriangulatedPoints`` in
:mod:`triangulation`, ``AffineFit`` in :mod:`vio_depth.rescale`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array


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
            raise ValueError("imu.t must be strictly increasing")

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
    load_disparity: Callable[[], np.ndarray] | None = field(default=None, repr=False)
    velocity_w: np.ndarray | None = None
    disparity_is_simulated: bool = False

    def image(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB image."""
        return self.load_image()

    def gt_depth(self) -> np.ndarray | None:
        """(H, W) float32 metres, 0 = invalid; None when the sequence has no depth."""
        return None if self.load_gt_depth is None else self.load_gt_depth()

    def disparity(self) -> np.ndarray | None:
        """(H, W) float32 affine-invariant disparity (bigger = nearer); None if absent."""
        return None if self.load_disparity is None else self.load_disparity()


class FrameStatus(str, enum.Enum):
    """Outcome of one frame. Anything other than OK / FALLBACK_* means no metric depth."""

    OK = "ok"
    FALLBACK_SCALE_ONLY = "fallback_scale_only"
    FALLBACK_PREVIOUS_FIT = "fallback_previous_fit"
    NO_PAIR = "no_pair"
    NO_POSE = "no_pose"
    TOO_FEW_MATCHES = "too_few_matches"
    TOO_FEW_POINTS = "too_few_points"
    ILL_CONDITIONED = "ill_conditioned"
    NO_CONSENSUS = "no_consensus"
    NO_DISPARITY = "no_disparity"

    @property
    def has_depth(self) -> bool:
        return self in (FrameStatus.OK, FrameStatus.FALLBACK_SCALE_ONLY, FrameStatus.FALLBACK_PREVIOUS_FIT)


@dataclass
class FrameResult:
    """What the pipeline produced for one frame (one line of ``frames.jsonl``).

    ``depth`` is (H, W) float32 metres with NaN where invalid (or None without metric depth);
    ``disparity`` the (H, W) input disparity; ``fit`` the ``AffineFit`` used;
    ``points_uv`` (N, 2) raw px / ``points_depth`` (N,) metres the metric points fed to the fit,
    ``points_sigma`` (N,) metres their 1-sigma depth (None when unknown) and ``points_inlier``
    (N,) bool whether each is an inlier of this frame's own fit (full or scale-only).
    ``extra`` holds JSON-able diagnostics written to ``frames.jsonl``.
    """

    frame: int
    stem: str
    status: FrameStatus
    reason: str = ""
    partner: int | None = None
    matches: int = 0
    triangulated: int = 0
    inliers: int = 0
    alpha: float | None = None
    beta: float | None = None
    r2: float | None = None
    seconds: float = 0.0
    depth: np.ndarray | None = field(default=None, repr=False)
    disparity: np.ndarray | None = field(default=None, repr=False)
    fit: object = field(default=None, repr=False)
    points_uv: np.ndarray | None = field(default=None, repr=False)
    points_depth: np.ndarray | None = field(default=None, repr=False)
    # issue 13 (exports): per-point 1-sigma depth in metres (None: unknown) and fit-inlier flags, (N,) each
    points_sigma: np.ndarray | None = field(default=None, repr=False)
    points_inlier: np.ndarray | None = field(default=None, repr=False)
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        out = {
            "frame": self.frame,
            "stem": self.stem,
            "partner_keyframe": self.partner,
            "matches": self.matches,
            "triangulated_points": self.triangulated,
            "inliers": self.inliers,
            "alpha": self.alpha,
            "beta": self.beta,
            "r2": self.r2,
            "status": self.status.value,
            "reason": self.reason,
            "seconds": round(self.seconds, 4),
        }
        out.update({k: v for k, v in self.extra.items() if _is_json_scalar(v)})
        return out


def _is_json_scalar(value) -> bool:
    if isinstance(value, dict):
        return all(isinstance(k, str) and _is_json_scalar(v) for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return all(_is_json_scalar(v) for v in value)
    return value is None or isinstance(value, (bool, int, float, str))
