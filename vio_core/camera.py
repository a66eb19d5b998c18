"""Pinhole camera with optional radial-tangential (OpenCV) or equidistant (fisheye) distortion."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .checks import check_array
from .errors import InputError

#: distortion models of :class:`Camera` (``model`` field)
DISTORTION_MODELS = ("radtan", "equidistant")
#: largest round-trip error (px) of undistort + distort over the image, see Camera.distortion_problem
MAX_DISTORTION_ROUNDTRIP_PX = 0.5
#: the radial factor (distorted / ideal radius, or theta_d / theta) must stay within these bounds
DISTORTION_FACTOR_RANGE = (0.6, 1.4)


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics in pixels for an image of ``width`` x ``height`` pixels.

    ``model`` names the lens distortion of the *raw* images and ``dist`` its coefficients:

    * ``"radtan"`` (default): OpenCV radial-tangential ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``
      (Kalibr / EuRoC "radial-tangential"), or empty for an undistorted (or rectified) camera;
    * ``"equidistant"``: the fisheye model of ``cv2.fisheye`` (Kalibr / TUM-VI
      "equidistant"), ``(k1, k2, k3, k4)``: a ray at angle ``theta`` from the optical axis
      lands at ideal radius ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 +
      k4 theta^8)`` (normalised units), or empty (no distortion).

    Keypoints are measured in raw pixel coordinates; :meth:`undistort_points` maps them to
    the ideal pinhole image with the same ``K`` before any geometry is done on them.

    Coefficients must be finite and describe a lens (:meth:`distortion_problem`): the
    model must map the image one-to-one, be invertible, and scale no pixel's distance from
    the principal point beyond :data:`DISTORTION_FACTOR_RANGE`; otherwise construction
    fails, since every point triangulated through such a model is wrong.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = field(default=())
    model: str = "radtan"

    def __post_init__(self):
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"camera: image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise InputError(f"camera: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if self.model not in DISTORTION_MODELS:
            raise InputError(f"camera: unknown distortion model {self.model!r}; valid: {', '.join(DISTORTION_MODELS)}")
        if self.model == "radtan" and len(self.dist) not in (0, 4, 5, 8):
            raise InputError(f"camera: expected 0, 4, 5 or 8 radial-tangential coefficients, got {len(self.dist)}")
        if self.model == "equidistant" and len(self.dist) not in (0, 4):
            raise InputError(f"camera: expected 0 or 4 equidistant coefficients (k1 k2 k3 k4), got {len(self.dist)}")
        object.__setattr__(self, "dist", tuple(float(d) for d in self.dist))
        if not all(np.isfinite(self.dist)):
            raise InputError(f"camera: distortion coefficients must be finite, got {self.dist}")
        problem = self.distortion_problem()
        if problem:
            raise InputError(f"camera: implausible distortion coefficients {list(self.dist)}: {problem}")

    def distortion_problem(self) -> str:
        """Why the distortion coefficients cannot describe a lens for this image ("" if they can).

        Checked on a 13 x 13 grid of raw pixels covering the whole image (corners included):

        1. the distorted radius ``r f(r)``, ``f(r) = 1 + k1 r^2 + k2 r^4 + k3 r^6`` (divided by
           the rational terms of an 8-coefficient model), must increase with the ideal
           radius ``r`` up to 1.05 x the image's largest ideal radius: a lens maps each ray
           to one pixel;
        2. undistorting the grid and distorting it again must return every pixel within
           :data:`MAX_DISTORTION_ROUNDTRIP_PX` (OpenCV's iterative undistortion converges);
        3. the radial factor ``f(r)`` must stay within :data:`DISTORTION_FACTOR_RANGE`
           (0.6 - 1.4) over that range: no pixel's distance from the principal point is
           scaled by more than 40 %.

        Real lenses pass with a margin: f over the image is 0.73-1.00 for KITTI raw
        (k1 = -0.37) and EuRoC (k1 = -0.28), 1.00-1.05 for TUM Freiburg 1; coefficients that
        fail would put triangulated points tens of percent off (issue 12: "every frame ok,
        points 131 % off"). Tangential terms are covered by checks 2 and 3 only.

        The equidistant (fisheye) model is checked on its own terms: ``theta_d = theta g(theta)``
        with ``g = 1 + k1 theta^2 + ... + k4 theta^8`` must increase with the ray angle
        ``theta`` and reach the image's largest distorted radius, and ``g`` must stay within
        :data:`DISTORTION_FACTOR_RANGE` (real fisheye lenses: TUM-VI, |k| ~ 1e-3, g within
        1 % of 1). No round trip through the pinhole image: a fisheye's corners may lie
        beyond 90 degrees, where no pinhole pixel exists.
        """
        if not self.is_distorted:
            return ""
        if self.model == "equidistant":
            return self._equidistant_problem()
        u = np.linspace(0.0, self.width - 1.0, 13)
        v = np.linspace(0.0, self.height - 1.0, 13)
        grid = np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)
        ideal = self.undistort_points(grid)
        if not np.all(np.isfinite(ideal)):
            return "undistortion gives non-finite pixels"
        r_ideal = np.hypot((ideal[:, 0] - self.cx) / self.fx, (ideal[:, 1] - self.cy) / self.fy)
        r = np.linspace(0.0, 1.05 * float(r_ideal.max()), 400)
        k = list(self.dist) + [0.0] * (8 - len(self.dist))
        r2 = r * r
        radial = (1 + k[0] * r2 + k[1] * r2**2 + k[4] * r2**3) / (1 + k[5] * r2 + k[6] * r2**2 + k[7] * r2**3)
        if not np.all(np.diff(r * radial) > 0):
            return "the radial distortion folds over inside the image (not one-to-one)"
        back = self.distort_points(ideal)
        roundtrip = float(np.max(np.linalg.norm(back - grid, axis=1)))
        if not roundtrip <= MAX_DISTORTION_ROUNDTRIP_PX:
            return f"undistorting and re-distorting moves pixels by up to {roundtrip:.3g} px (not invertible)"
        lo, hi = DISTORTION_FACTOR_RANGE
        if not (lo <= float(radial.min()) and float(radial.max()) <= hi):
            return (f"it scales radii in the image by {float(radial.min()):.2f}-{float(radial.max()):.2f} "
                    f"(a lens stays within {lo}-{hi})")
        return ""

    def _equidistant_problem(self) -> str:
        corners = np.array([[0.0, 0.0], [self.width - 1.0, 0.0], [0.0, self.height - 1.0],
                            [self.width - 1.0, self.height - 1.0]])
        theta_d_max = float(np.max(np.hypot((corners[:, 0] - self.cx) / self.fx, (corners[:, 1] - self.cy) / self.fy)))
        theta = np.linspace(0.0, min(np.pi, 1.5 * theta_d_max + 0.05), 400)
        t2 = theta * theta
        k1, k2, k3, k4 = self.dist
        g = 1 + k1 * t2 + k2 * t2**2 + k3 * t2**3 + k4 * t2**4
        theta_d = theta * g
        reach = np.flatnonzero(theta_d >= theta_d_max)
        end = int(reach[0]) + 1 if len(reach) else len(theta)
        if not (len(reach) and np.all(np.diff(theta_d[:end]) > 0)):
            return "the fisheye distortion folds over or does not reach the image corners (not one-to-one)"
        lo, hi = DISTORTION_FACTOR_RANGE
        if not (lo <= float(g[:end].min()) and float(g[:end].max()) <= hi):
            return (f"it scales ray angles in the image by {float(g[:end].min()):.2f}-{float(g[:end].max()):.2f} "
                    f"(a lens stays within {lo}-{hi})")
        return ""

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def is_distorted(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    @classmethod
    def from_K(cls, K, width: int, height: int, dist=(), model: str = "radtan") -> "Camera":
        """Build from a (3, 3) intrinsic matrix (zero skew)."""
        K = check_array("K", K, (3, 3), finite=True)
        return cls(int(width), int(height), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                   tuple(dist), model)

    def project(self, points_c) -> tuple[np.ndarray, np.ndarray]:
        """Project ``points_c: (N, 3)`` metres (camera frame, z forward) to ideal pixels.

        Returns ``uv: (N, 2)`` pixels of the undistorted pinhole image and
        ``depth: (N,)`` metres (z). Points with z <= 0 get NaN pixel coordinates; a point
        just in front of the camera may project to +-inf (no warning).
        """
        p = check_array("points_c", points_c, (None, 3))
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
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
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
        if self.model == "equidistant":
            out = cv2.fisheye.undistortPoints(uv_raw.reshape(-1, 1, 2).astype(np.float64), self.K,
                                              np.asarray(self.dist), R=np.eye(3), P=self.K, criteria=criteria)
            return out.reshape(-1, 2)
        out = cv2.undistortPoints(
            uv_raw.reshape(-1, 1, 2).astype(np.float64),
            self.K,
            np.asarray(self.dist),
            R=None,
            P=self.K,
            criteria=criteria,
        )
        return out.reshape(-1, 2)

    def distort_points(self, uv_ideal) -> np.ndarray:
        """Map ideal pinhole pixels ``uv_ideal: (N, 2)`` to raw (distorted) pixels."""
        uv = check_array("uv_ideal", uv_ideal, (None, 2))
        if not self.is_distorted or len(uv) == 0:
            return uv.astype(np.float64, copy=True)
        if self.model == "equidistant":
            xy = np.stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy], 1)
            out = cv2.fisheye.distortPoints(xy.reshape(-1, 1, 2), self.K, np.asarray(self.dist))
            return out.reshape(-1, 2)
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
            self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, self.dist, self.model,
        )
