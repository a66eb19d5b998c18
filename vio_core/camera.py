"""Pinhole camera with optional radial-tangential (OpenCV) distortion."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .checks import check_array
from .errors import InputError


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics in pixels for an image of ``width`` x ``height`` pixels.

    ``dist`` holds OpenCV radial-tangential coefficients ``(k1, k2, p1, p2[, k3])`` of
    the *raw* images, or is empty for an undistorted (or rectified) camera. Keypoints
    are measured in raw pixel coordinates; :meth:`undistort_points` maps them to the
    ideal pinhole image with the same ``K`` before any geometry is done on them.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = field(default=())

    def __post_init__(self):
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"camera: image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise InputError(f"camera: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if len(self.dist) not in (0, 4, 5, 8):
            raise InputError(f"camera: expected 0, 4, 5 or 8 distortion coefficients, got {len(self.dist)}")
        object.__setattr__(self, "dist", tuple(float(d) for d in self.dist))

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def is_distorted(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    @classmethod
    def from_K(cls, K, width: int, height: int, dist=()) -> "Camera":
        """Build from a (3, 3) intrinsic matrix (zero skew)."""
        K = check_array("K", K, (3, 3), finite=True)
        return cls(int(width), int(height), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), tuple(dist))

    def project(self, points_c) -> tuple[np.ndarray, np.ndarray]:
        """Project ``points_c: (N, 3)`` metres (camera frame, z forward) to ideal pixels.

        Returns ``uv: (N, 2)`` pixels of the undistorted pinhole image and
        ``depth: (N,)`` metres (z). Points with z <= 0 get NaN pixel coordinates.
        """
        p = check_array("points_c", points_c, (None, 3))
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(z > 0, self.fx * p[:, 0] / z + self.cx, np.nan)
            v = np.where(z > 0, self.fy * p[:, 1] / z + self.cy, np.nan)
        return np.stack([u, v], axis=1), z

    def backproject(self, uv, depth) -> np.ndarray:
        """Ideal pixels ``uv: (N, 2)`` with ``depth: (N,)`` metres -> ``points_c: (N, 3)`` metres."""
        uv = check_array("uv", uv, (None, 2))
        depth = check_array("depth", depth, (uv.shape[0],))
        x = (uv[:, 0] - self.cx) / self.fx
        y = (uv[:, 1] - self.cy) / self.fy
        return np.stack([x * depth, y * depth, depth], axis=1)

    def undistort_points(self, uv_raw) -> np.ndarray:
        """Map raw pixels ``uv_raw: (N, 2)`` to ideal pinhole pixels with the same K.

        Identity (a copy) when the camera has no distortion.
        """
        uv_raw = check_array("uv_raw", uv_raw, (None, 2))
        if not self.is_distorted or len(uv_raw) == 0:
            return uv_raw.astype(np.float64, copy=True)
        out = cv2.undistortPoints(
            uv_raw.reshape(-1, 1, 2).astype(np.float64),
            self.K,
            np.asarray(self.dist),
            R=None,
            P=self.K,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
        )
        return out.reshape(-1, 2)

    def distort_points(self, uv_ideal) -> np.ndarray:
        """Map ideal pinhole pixels ``uv_ideal: (N, 2)`` to raw (distorted) pixels."""
        uv = check_array("uv_ideal", uv_ideal, (None, 2))
        if not self.is_distorted or len(uv) == 0:
            return uv.astype(np.float64, copy=True)
        rays = np.stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy, np.ones(len(uv))], 1)
        out, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, np.asarray(self.dist))
        return out.reshape(-1, 2)

    def in_image(self, uv, margin: float = 0.0) -> np.ndarray:
        """(N,) bool: pixels ``uv: (N, 2)`` inside the image (minus ``margin`` px)."""
        uv = check_array("uv", uv, (None, 2))
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= margin)
                & (uv[:, 0] <= self.width - 1 - margin)
                & (uv[:, 1] >= margin)
                & (uv[:, 1] <= self.height - 1 - margin)
            )

    def scaled(self, sx: float, sy: float | None = None) -> "Camera":
        """Camera for the image resized by ``sx`` (and ``sy``), pixel-centre convention."""
        sy = sx if sy is None else sy
        return Camera(
            max(1, round(self.width * sx)), max(1, round(self.height * sy)),
            self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, self.dist,
        )
